#include "engine/core/parallel.h"

#include <gtest/gtest.h>

#include <vector>

namespace reflcap {
namespace {

TEST(ParallelFor, VisitsEveryIndexExactlyOnce) {
  std::vector<int> hits(10007, 0);
  ParallelFor(0, int64_t(hits.size()), 97, [&](int64_t b, int64_t e, int) {
    for (int64_t i = b; i < e; ++i) hits[i]++;
  });
  for (int h : hits) ASSERT_EQ(h, 1);
}

}  // namespace
}  // namespace reflcap
