// Crc32 (sample_store.h): CRC-32 (IEEE 802.3 / zlib) by carry-less multiplication where the CPU
// has it, zlib's table-driven loop elsewhere and for the last bytes.
//
// The sample store checks ~52 bytes per sample on every read: at zlib's ~1.8 GB/s the checksum
// was the largest part of reading a store (a fit merge re-reads the whole million-preset store,
// 1.8 GB). Folding 64 bytes per step with PCLMULQDQ runs at ~10+ GB/s.
//
// How it works (our derivation). Read a 128-bit register as a polynomial over GF(2) in the
// reflected order CRC-32 uses: bit k is the coefficient of x^(127-k), so the low 64 bits hold
// the high-degree half. The message is a polynomial M whose first bit has the highest degree;
// the CRC is M * x^32 mod P (after XOR-ing the initial value into the first 32 bits).
// Folding: a 128-bit block R = H * x^64 + L that lies D bits before another block B contributes
// R * x^D; replace it by H * (x^(D+64) mod P) + L * (x^D mod P), which has degree < 96, fits in
// 128 bits, and is congruent mod P, and XOR it into B. A carry-less product of two 64-bit
// reflected operands comes out multiplied by x once more (bit k of the product holds the
// degree-(126-k) terms), so the constants are x^(D+63) and x^(D-1) mod P. Four independent
// lanes fold by D = 512 bits; at the end they fold into one (D = 384, 256, 128), whole 16-byte
// blocks follow with D = 128, and the remaining 16 + (< 16) bytes, whose polynomial is congruent
// to the message's, go through zlib from a zero state.
#include <zlib.h>

#include <array>
#include <cstring>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "engine/texel/sample_store.h"

namespace reflcap {
namespace {

// zlib's crc32_z for a continuation; a null buffer would restart it (zlib's convention).
uint32_t ZlibCrc(uint32_t crc, const uint8_t* p, size_t n) {
  if (n == 0) return crc;
  return uint32_t(crc32_z(uLong(crc), p, z_size_t(n)));
}

#if defined(__x86_64__)

// x^n mod P, P = x^32 + 0x04C11DB7 (normal order: bit d = coefficient of x^d).
uint64_t XPowModP(int n) {
  uint64_t v = 1;
  for (int i = 0; i < n; ++i) {
    v <<= 1;
    if (v & (uint64_t{1} << 32)) v ^= 0x104C11DB7u;
  }
  return v;
}

uint64_t Reverse64(uint64_t v) {
  uint64_t r = 0;
  for (int i = 0; i < 64; ++i) r |= ((v >> i) & 1) << (63 - i);
  return r;
}

// The folding constants for distance `bits`: low qword multiplies the register's low half (the
// high-degree terms), high qword its high half.
struct FoldConstant {
  uint64_t lo, hi;
};
FoldConstant ConstantFor(int bits) {
  return {Reverse64(XPowModP(bits + 63)), Reverse64(XPowModP(bits - 1))};
}

struct Constants {
  FoldConstant d512 = ConstantFor(512), d384 = ConstantFor(384), d256 = ConstantFor(256),
               d128 = ConstantFor(128);
};
const Constants& Folds() {
  static const Constants constants;
  return constants;
}

__attribute__((target("pclmul,sse4.1"))) inline __m128i Fold(__m128i x, __m128i k, __m128i data) {
  const __m128i a = _mm_clmulepi64_si128(x, k, 0x00);  // low half x its constant
  const __m128i b = _mm_clmulepi64_si128(x, k, 0x11);  // high half x its constant
  return _mm_xor_si128(_mm_xor_si128(a, b), data);
}

__attribute__((target("pclmul,sse4.1"))) inline __m128i Load(const FoldConstant& c) {
  return _mm_set_epi64x(int64_t(c.hi), int64_t(c.lo));
}

__attribute__((target("pclmul,sse4.1"))) uint32_t CrcClmul(uint32_t crc, const uint8_t* p, size_t n) {
  // n >= 64. The initial value (the complement of the running CRC) enters the first 32 bits.
  const Constants& k = Folds();
  const __m128i init = _mm_cvtsi32_si128(int(~crc));
  __m128i x0 = _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)), init);
  __m128i x1 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 16));
  __m128i x2 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 32));
  __m128i x3 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 48));
  p += 64;
  n -= 64;
  const __m128i k512 = Load(k.d512);
  while (n >= 64) {
    x0 = Fold(x0, k512, _mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
    x1 = Fold(x1, k512, _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 16)));
    x2 = Fold(x2, k512, _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 32)));
    x3 = Fold(x3, k512, _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 48)));
    p += 64;
    n -= 64;
  }
  // The four lanes into one: x0 lies 384 bits before x3, x1 256, x2 128.
  __m128i x = Fold(x0, Load(k.d384), x3);
  x = Fold(x1, Load(k.d256), x);
  x = Fold(x2, Load(k.d128), x);
  const __m128i k128 = Load(k.d128);
  while (n >= 16) {
    x = Fold(x, k128, _mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
    p += 16;
    n -= 16;
  }
  uint8_t block[16];
  _mm_storeu_si128(reinterpret_cast<__m128i*>(block), x);
  // From a zero state (zlib's argument is the complement of its state) over the folded block,
  // then the tail.
  return ZlibCrc(ZlibCrc(0xFFFFFFFFu, block, 16), p, n);
}

bool HaveClmul() {
  static const bool have = [] {
    __builtin_cpu_init();  // may run before libgcc's own initialiser (static initialisation)
    return __builtin_cpu_supports("pclmul") && __builtin_cpu_supports("sse4.1");
  }();
  return have;
}

#endif  // __x86_64__

}  // namespace

uint32_t Crc32(const void* data, size_t size, uint32_t crc) {
  const auto* p = static_cast<const uint8_t*>(data);
#if defined(__x86_64__)
  // Below 64 bytes the four lanes do not fill: the table loop is as fast there.
  if (size >= 64 && HaveClmul()) return CrcClmul(crc, p, size);
#endif
  return ZlibCrc(crc, p, size);
}

}  // namespace reflcap
