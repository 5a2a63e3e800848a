/* Reductions over any set of axes: the ONNX Reduce* family (Sum, Mean, Max, Min, Prod,
 * L1, L2, SumSquare, LogSum, LogSumExp).
 *
 * The host coalesces the input into at most four kept dimensions [K0, K1, K2, K3] (the
 * output's shape, keepdims or not) and at most four reduced ones [R0, R1, R2, R3], each
 * with the input's element strides (clss/ops/reduce.py). One work-item per output
 * element, NDRange (K3, K2, K0*K1): dimension 0 walks the contiguous output. Each
 * work-item walks its reduced elements with the innermost reduced dimension in its
 * inner loop: eight lanes at a time when that dimension is contiguous (a spatial mean,
 * a LayerNorm-style row), else one at a time (a channel reduction, where neighbouring
 * work-items read neighbouring elements).
 *
 * Accumulation is in float (A) whatever the storage; sums are taken per inner row and
 * added to the total row by row, so a 1080p spatial mean adds rows of 1920, not 2 million
 * values into one float.
 *
 * Build options:
 *   -DROP=n   the reduction (ROP_* below)
 *   -DCLSS_CLANG_VECTORS=0|1  loads through common.h's FLD/FLD8 as clang vector accesses
 *             (1, on PoCL, where vload8/vload_half are out-of-line calls) or the builtins
 */
#include "common.h"

#define ROP_SUM 0
#define ROP_MEAN 1
#define ROP_MAX 2
#define ROP_MIN 3
#define ROP_PROD 4
#define ROP_L1 5
#define ROP_L2 6
#define ROP_SUMSQ 7
#define ROP_LOGSUM 8
#define ROP_LOGSUMEXP 9

#ifndef ROP
#define ROP ROP_SUM
#endif

/* MAP: what each element contributes; COMBINE: how contributions meet; INIT: the
 * identity (also the result of an empty reduction, as ONNX defines it). Max and min
 * propagate NaN, as onnxruntime does (fmax/fmin would drop it); NaN is tested as v != v,
 * which PoCL does not turn into a library call as it does isnan. LogSumExp subtracts the
 * maximum first (a pass of its own), so MAP sees m. */
#if ROP == ROP_MAX
#define INIT (-INFINITY)
#define COMBINE(s, v) ((((v) > (s)) | ((v) != (v))) ? (v) : (s))
#define MAP(x) (x)
#elif ROP == ROP_MIN
#define INIT INFINITY
#define COMBINE(s, v) ((((v) < (s)) | ((v) != (v))) ? (v) : (s))
#define MAP(x) (x)
#elif ROP == ROP_PROD
#define INIT 1.0f
#define COMBINE(s, v) ((s) * (v))
#define MAP(x) (x)
#else
#define INIT 0.0f
#define COMBINE(s, v) ((s) + (v))
#if ROP == ROP_L1
#define MAP(x) fabs(x)
#elif ROP == ROP_L2 || ROP == ROP_SUMSQ
#define MAP(x) ((x) * (x))
#elif ROP == ROP_LOGSUMEXP
#define MAP(x) exp((x) - m)
#else
#define MAP(x) (x)
#endif
#endif

/* The result from the combined contributions (generic in the vector width). */
#if ROP == ROP_MEAN
#define FINISH(acc) ((acc) / count)
#elif ROP == ROP_L2
#define FINISH(acc) sqrt(acc)
#elif ROP == ROP_LOGSUM
#define FINISH(acc) log(acc)
#elif ROP == ROP_LOGSUMEXP
#define FINISH(acc) (m + log(acc))
#else
#define FINISH(acc) (acc)
#endif

/* One reduced row of R3 elements at p (stride r3) folded into a fresh accumulator. */
#define ROW_FOLD(row, p, R3, r3)                                               \
    do {                                                                       \
        row = (float)INIT;                                                     \
        int e = 0;                                                             \
        if ((r3) == 1 && (R3) >= 8) {                                          \
            float8 v8 = (float8)((float)INIT);                                 \
            for (; e + 8 <= (R3); e += 8) {                                    \
                const float8 x = convert_float8(FLD8(p, e));                    \
                v8 = COMBINE(v8, MAP(x));                                      \
            }                                                                  \
            row = COMBINE(row, v8.s0); row = COMBINE(row, v8.s1);              \
            row = COMBINE(row, v8.s2); row = COMBINE(row, v8.s3);              \
            row = COMBINE(row, v8.s4); row = COMBINE(row, v8.s5);              \
            row = COMBINE(row, v8.s6); row = COMBINE(row, v8.s7);              \
        }                                                                      \
        for (; e < (R3); ++e) {                                                \
            const float x = (float)FLD(p, (long)e * (r3));                      \
            row = COMBINE(row, MAP(x));                                        \
        }                                                                      \
    } while (0)

/* The reduction of one output: the elements at base + a*r0 + b*r1 + c*r2 + e*r3. */
inline float reduce_one(__global const T *in, long base, int R0, int R1, int R2, int R3,
                        int r0, int r1, int r2, int r3, float count)
{
#if ROP == ROP_LOGSUMEXP
    float m = -INFINITY;
    for (int a = 0; a < R0; ++a)
        for (int b = 0; b < R1; ++b)
            for (int c = 0; c < R2; ++c) {
                __global const T *p = in + base + (long)a * r0 + (long)b * r1 + (long)c * r2;
                for (int e = 0; e < R3; ++e) {
                    const float x = (float)FLD(p, (long)e * r3);
                    m = (x > m || isnan(x)) ? x : m;
                }
            }
    if (isinf(m))          /* all -inf (or empty): exp(x - m) would be NaN */
        m = 0.0f;
#endif
    float acc = (float)INIT;
    for (int a = 0; a < R0; ++a)
        for (int b = 0; b < R1; ++b)
            for (int c = 0; c < R2; ++c) {
                __global const T *p = in + base + (long)a * r0 + (long)b * r1 + (long)c * r2;
                float row;
                ROW_FOLD(row, p, R3, r3);
                acc = COMBINE(acc, row);
            }
    return FINISH(acc);
}

/** @param[in]  in      the input
 *  @param[out] out     [K0, K1, K2, K3] the reduction (contiguous)
 *  @param[in]  K1, K2, K3  the kept (output) dimensions 1-3
 *  @param[in]  K01     K0 * K1, the extent of NDRange dimension 2
 *  @param[in]  k0..k3  input element strides of the kept dimensions
 *  @param[in]  R0..R3  the reduced dimensions (1 where unused)
 *  @param[in]  r0..r3  input element strides of the reduced dimensions
 *  @param[in]  count   reduced elements per output (Mean's divisor)
 *  @note -DROP=n: the reduction (ROP_* above); -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void reduce(__global const T *in, __global T *out, int K1, int K2, int K3, int K01,
                     int k0, int k1, int k2, int k3, int R0, int R1, int R2, int R3,
                     int r0, int r1, int r2, int r3, float count)
{
    const int i3 = get_global_id(0), i2 = get_global_id(1), z = get_global_id(2);
    if (i3 >= K3 || i2 >= K2 || z >= K01) return;
    const int i0 = z / K1, i1 = z % K1;
    const long base = (long)i0 * k0 + (long)i1 * k1 + (long)i2 * k2 + (long)i3 * k3;
    FST(out, ((long)z * K2 + i2) * K3 + i3, reduce_one(in, base, R0, R1, R2, R3, r0, r1, r2, r3, count));
}

/* reduce with eight neighbouring outputs per work-item, for outputs that are neighbours in
 * the input too (k3 == 1: a reduction over channels, or over any axis but the last): each
 * reduced element is one eight-wide load for all eight outputs. The host's fast path
 * (reduce.outputs8 in clss/ops/reduce.py; `reduce` is its reference). Same arguments;
 * NDRange (ceil(K3 / 8), K2, K0*K1). */
/** @param[in]  in      the input
 *  @param[out] out     [K0, K1, K2, K3] the reduction (contiguous)
 *  @param[in]  K1, K2, K3  the kept (output) dimensions 1-3
 *  @param[in]  K01     K0 * K1, the extent of NDRange dimension 2
 *  @param[in]  k0..k3  input element strides of the kept dimensions (k3 == 1)
 *  @param[in]  R0..R3  the reduced dimensions (1 where unused)
 *  @param[in]  r0..r3  input element strides of the reduced dimensions
 *  @param[in]  count   reduced elements per output (Mean's divisor)
 *  @note -DROP=n: the reduction (ROP_* above); -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void reduce8(__global const T *in, __global T *out, int K1, int K2, int K3, int K01,
                      int k0, int k1, int k2, int k3, int R0, int R1, int R2, int R3,
                      int r0, int r1, int r2, int r3, float count)
{
    const int i3 = get_global_id(0) * 8, i2 = get_global_id(1), z = get_global_id(2);
    if (i3 >= K3 || i2 >= K2 || z >= K01) return;
    const int i0 = z / K1, i1 = z % K1;
    const long base = (long)i0 * k0 + (long)i1 * k1 + (long)i2 * k2 + (long)i3;
    const long o = ((long)z * K2 + i2) * K3 + i3;
    if (i3 + 8 > K3) {
        for (int e = 0; i3 + e < K3; ++e)
            FST(out, o + e, reduce_one(in, base + e, R0, R1, R2, R3, r0, r1, r2, r3, count));
        return;
    }
#if ROP == ROP_LOGSUMEXP
    float8 m = (float8)(-INFINITY);
    for (int a = 0; a < R0; ++a)
        for (int b = 0; b < R1; ++b)
            for (int c = 0; c < R2; ++c)
                for (int e = 0; e < R3; ++e) {
                    const float8 x = convert_float8(FLD8(in, base + (long)a * r0 + (long)b * r1 +
                                                             (long)c * r2 + (long)e * r3));
                    m = ((x > m) | (x != x)) ? x : m;
                }
    m = isinf(m) ? (float8)(0.0f) : m;
#endif
    float8 acc = (float8)((float)INIT);
    for (int a = 0; a < R0; ++a)
        for (int b = 0; b < R1; ++b)
            for (int c = 0; c < R2; ++c) {
                float8 row = (float8)((float)INIT);
                __global const T *p = in + base + (long)a * r0 + (long)b * r1 + (long)c * r2;
                for (int e = 0; e < R3; ++e) {
                    const float8 x = convert_float8(FLD8(p, (long)e * r3));
                    row = COMBINE(row, MAP(x));
                }
                acc = COMBINE(acc, row);
            }
    FST8(out, o, CONVERT_A8(FINISH(acc)));
}
