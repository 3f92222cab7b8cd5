// LargeBufferVector: large buffers mapped on their own, 2 MiB-aligned; small ones work as any
// vector's; contents kept through growth, copies and moves.
#include "engine/core/large_buffer.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <numeric>
#include <utility>

namespace reflcap {
namespace {

constexpr uintptr_t kHugePage = uintptr_t{2} << 20;

struct Record {  // a 52-byte record, as the sample store's
  float values[12];
  uint32_t index;
};

TEST(LargeBufferVector, LargeBuffersAreHugePageAlignedAndKeepTheirContents) {
  LargeBufferVector<Record> v;
  const size_t large = 3 * kLargeBufferBytes / sizeof(Record) + 7;  // not a whole page
  v.resize(large);
  ASSERT_EQ(reinterpret_cast<uintptr_t>(v.data()) % kHugePage, 0u);
  for (size_t i = 0; i < v.size(); ++i) {
    v[i].index = uint32_t(i);
    v[i].values[11] = float(i % 1000);
  }
  // Growth moves the elements into a new mapping; a copy makes another.
  v.resize(2 * large);
  for (size_t i = large; i < v.size(); ++i) v[i].index = uint32_t(i);
  const LargeBufferVector<Record> copy = v;
  ASSERT_EQ(reinterpret_cast<uintptr_t>(copy.data()) % kHugePage, 0u);
  for (size_t i = 0; i < copy.size(); ++i) {
    ASSERT_EQ(copy[i].index, uint32_t(i)) << i;
    if (i < large) ASSERT_EQ(copy[i].values[11], float(i % 1000)) << i;
  }
  LargeBufferVector<Record> moved = std::move(v);
  EXPECT_EQ(moved.size(), 2 * large);
  EXPECT_EQ(moved.back().index, uint32_t(2 * large - 1));
  moved.clear();
  moved.shrink_to_fit();  // the mapping is given back (munmap of the rounded length)
  EXPECT_EQ(moved.capacity(), 0u);
}

TEST(LargeBufferVector, SmallBuffersWorkAndGrowIntoAMapping) {
  LargeBufferVector<uint32_t> v(100);
  std::iota(v.begin(), v.end(), 0u);
  EXPECT_EQ(std::accumulate(v.begin(), v.end(), 0u), 4950u);
  v.assign(kLargeBufferBytes / sizeof(uint32_t), 5u);  // crosses into a mapping
  EXPECT_EQ(reinterpret_cast<uintptr_t>(v.data()) % kHugePage, 0u);
  EXPECT_EQ(v.front() + v.back(), 10u);
}

}  // namespace
}  // namespace reflcap
