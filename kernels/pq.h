/* The SMPTE ST 2084 (PQ) transfer of clss.pipeline.contract, written once for every frame
 * step whose colour lives in PQ: linear * pq_scale (nits / 10000) in, [0, 1] out, and back
 * (inv_pq_scale = 10000 / nits).
 *
 * PQ_ENCODE(T, NAME, POW) and PQ_DECODE(T, NAME, POW, MAX, CLAMP) define the two functions
 * over a float type T (float, float8, a kernel's own pixel vector) with a power function
 * POW(x, y) for x >= 0, and the decode's max and clamp: every kernel then computes the same
 * operations in the same order, and differs only where it chose to (the exp2/log2 form or
 * the library pow; max or NaN-aware fmax; builtin or inline clamp). The including kernel writes the qualifier
 * (`static`, `inline`) in front, and its FP_CONTRACT state holds in the expansion.
 * Below: pq_encode, pq_decode and pq_decode8 with powp (exp2/log2, 0 at 0); a kernel with
 * pixel vectors of its own, or the library pow, instantiates its own pair.
 */
#ifndef CLSS_PQ_H
#define CLSS_PQ_H

/* The contract's constants; a host may pass them as -D options too. */
#ifndef PQ_M1
#define PQ_M1 0.1593017578125f
#define PQ_M2 78.84375f
#define PQ_C1 0.8359375f
#define PQ_C2 18.8515625f
#define PQ_C3 18.6875f
#endif

#define PQ_ENCODE(T, NAME, POW) PQ_ENCODE_C(T, NAME, POW, clamp)

/* the same with the kernel's own clamp (pq_clamp8: builtin clamp is a library call on PoCL) */
#define PQ_ENCODE_C(T, NAME, POW, CLAMP)                                              \
    T NAME(T x, float pq_scale)                                                       \
    {                                                                                 \
        const T y = CLAMP(x * pq_scale, 0.0f, 1.0f);                                  \
        const T ym = POW(y, (float)PQ_M1);                                            \
        return POW((PQ_C1 + PQ_C2 * ym) / (1.0f + PQ_C3 * ym), (float)PQ_M2);         \
    }

/* the encoded value is clamped to [0, 1] first */
#define PQ_DECODE(T, NAME, POW, MAX, CLAMP)                                           \
    T NAME(T e, float inv_pq_scale)                                                   \
    {                                                                                 \
        const T ep = POW(CLAMP(e, 0.0f, 1.0f), 1.0f / (float)PQ_M2);                  \
        return POW(MAX(ep - PQ_C1, 0.0f) / (PQ_C2 - PQ_C3 * ep), 1.0f / (float)PQ_M1) \
               * inv_pq_scale;                                                        \
    }

/* x^y for x >= 0 as exp2(y log2 x): PoCL's pow() is a library call of ~0.25 us, which made
 * the PQ decode of a 1080p frame take 2.6 s; exp2/log2 inline and agree to a few ulp. */
static float powp(float x, float y)
{
    return x > 0.0f ? exp2(y * log2(x)) : 0.0f;
}

static PQ_ENCODE(float, pq_encode, powp)
static PQ_DECODE(float, pq_decode, powp, max, clamp)

/* pq_decode on 8 values at once: the same operations lane by lane. Scalar exp2/log2 are
 * library calls on PoCL (about 0.2 us a decode: 1.3 s of a 1080p frame); on float8 they
 * vectorise. */
static float8 powp8(float8 x, float y)
{
    return x > 0.0f ? exp2(y * log2(x)) : (float8)(0.0f);
}

/* clamp and max of the decode as vector ?: (select, clamp and max are out-of-line calls on
 * pip's PoCL): equal to the builtins for every finite argument, and -0 cannot reach them
 * here (ep - C1 is +0 where ep == C1) */
static inline float8 pq_clamp8(float8 x, float lo, float hi)
{
    return x > lo ? (x < hi ? x : (float8)(hi)) : (float8)(lo);
}

static inline float8 pq_max8(float8 x, float z)
{
    return x > z ? x : (float8)(z);
}

static PQ_DECODE(float8, pq_decode8, powp8, pq_max8, pq_clamp8)

/* x^y for x >= 0 (0 at 0) on float8 in plain arithmetic, for the fast paths that take it
 * (bicubic.fused8, frame.pq_poly): the float8 exp2 and log2 are library calls on PoCL too,
 * and a call spills every live vector register. log2 x = the exponent of x plus an odd
 * series in s = (m - 1) / (m + 1) of its mantissa m in [sqrt(1/2), sqrt(2)) (|s| < 0.172,
 * terms to s^9: truncation below 1e-9; subnormal x scaled by 2^23 first); exp2 t = 2^n
 * (the exponent bits) times a degree-7 Taylor polynomial of f = t - n in [-1/2, 1/2]
 * (truncation below 1e-8 relative), n = t rounded to nearest by the 1.5 * 2^23 shift, t
 * clamped to [-126, 127]. Against float64 (a million arguments each): log2 within
 * 2.3e-7 relative, exp2 within 9.2e-8 relative (the library's float exp2: 2.2e-7), and
 * the PQ decode and encode as close to float64 pow as with the library's exp2 and log2
 * (0.53 and 0.13 of the fp32 tolerance; studies in docs/benchmarks.md, issue 51). */
#if defined(__clang__)
#define PQ_CVT(x, T) __builtin_convertvector((x), T)
#else
#define PQ_CVT(x, T) convert_##T(x)
#endif

/* pq_log2qN, pq_exp2qN, powqN (and pq_clampN, pq_maxN as pq_clamp8, pq_max8 above) on
 * floatN, N = 8 or 16: the decode of two channels as one float16 halves the length of
 * its chains of dependent operations on AVX-512 */
#define PQ_POWQ_FNS(N)                                                                    \
static inline float##N pq_log2q##N(float##N x)                                            \
{                                                                                         \
    const int##N sub = x < 1.17549435e-38f;                                               \
    x = sub ? x * 8388608.0f : x;                                                         \
    const int##N b = as_int##N(x);                                                        \
    float##N m = as_float##N((b & 0x007fffff) | 0x3f800000);                             \
    const int##N big = m > 1.41421356f;                                                   \
    m = big ? m * 0.5f : m;                                                               \
    /* comparisons are -1 where true */                                                   \
    const int##N e = ((b >> 23) & 0xff) - 127 - big + (sub & -23);                        \
    const float##N s = (m - 1.0f) / (m + 1.0f), s2 = s * s;                               \
    const float##N p = 2.885390043258667f + s2 * (0.9617967009544373f                     \
                       + s2 * (0.5770780444145203f + s2 * (0.41219857335090637f            \
                       + s2 * 0.32059890031814575f)));                                    \
    return PQ_CVT(e, float##N) + s * p;                                                   \
}                                                                                         \
                                                                                          \
static inline float##N pq_exp2q##N(float##N t)                                            \
{                                                                                         \
    t = t < -126.0f ? (float##N)(-126.0f) : (t > 127.0f ? (float##N)(127.0f) : t);        \
    const float##N r = (t + 12582912.0f) - 12582912.0f;                                   \
    const float##N f = t - r;                                                             \
    const int##N n = PQ_CVT(r, int##N);                                                   \
    const float##N p = 1.0f + f * (0.6931471824645996f + f * (0.24022650718688965f         \
                       + f * (0.05550410971045494f + f * (0.009618128649890423f            \
                       + f * (0.0013333557872101665f + f * (0.0001540352968731895f         \
                       + f * 1.5252733646775596e-05f))))));                               \
    return p * as_float##N((n + 127) << 23);                                              \
}                                                                                         \
                                                                                          \
static inline float##N powq##N(float##N x, float y)                                       \
{                                                                                         \
    return x > 0.0f ? pq_exp2q##N(y * pq_log2q##N(x)) : (float##N)(0.0f);                 \
}

PQ_POWQ_FNS(8)
PQ_POWQ_FNS(16)

static inline float16 pq_clamp16(float16 x, float lo, float hi)
{
    return x > lo ? (x < hi ? x : (float16)(hi)) : (float16)(lo);
}

static inline float16 pq_max16(float16 x, float z)
{
    return x > z ? x : (float16)(z);
}

static PQ_DECODE(float16, pq_decode16q, powq16, pq_max16, pq_clamp16)
static PQ_DECODE(float8, pq_decode8q, powq8, pq_max8, pq_clamp8)

#endif
