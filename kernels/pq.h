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

#define PQ_ENCODE(T, NAME, POW)                                                       \
    T NAME(T x, float pq_scale)                                                       \
    {                                                                                 \
        const T y = clamp(x * pq_scale, 0.0f, 1.0f);                                  \
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

#endif
