/* Peak probes (clpeak-style): the machine's FMA throughput and stream bandwidth,
 * measured on the same device and through the same OpenCL stack as the kernels,
 * so the bench can say what share of the attainable each kernel reaches.
 *
 * Build options:
 *   -DVW=1|2|4|8|16   vector width of each FMA chain (float, float2, ... float16).
 *                     VW=1 leaves vectorisation to the implementation; VW>1 is
 *                     explicit (float16 = two AVX2 registers per chain).
 *   -DCHAINS=n        independent chains per work-item (1, 2, 4, 8). One chain
 *                     is latency bound (4-5 cycles per FMA on current CPUs); a core
 *                     needs latency x FMA units chains in flight to reach its peak.
 *   -DREPEAT=n        FMAs per chain per loop iteration (default 16), so loop
 *                     overhead is negligible while the body stays small.
 *
 * The chains are written x * m + c under FP_CONTRACT, not mad()/fma(): on PoCL
 * (3.0, x86) the mad and fma builtins on vectors run several times slower than
 * a contracted multiply-add, and without contraction a multiply and an add issue
 * separately (half the peak). The chains take m and c as kernel arguments and
 * every step depends on the previous one, so the compiler can neither fold nor hoist them;
 * the result is stored, so they cannot be removed. With m slightly below 1 the
 * values converge to c / (1 - m) instead of overflowing or going denormal.
 * The host chooses `iters` so one launch lasts the target duration.
 */
#pragma OPENCL FP_CONTRACT ON

#ifndef VW
#define VW 8
#endif
#ifndef CHAINS
#define CHAINS 8
#endif
#ifndef REPEAT
#define REPEAT 16
#endif

#if VW == 1
typedef float V;
#define SUMV(v) (v)
#elif VW == 2
typedef float2 V;
#define SUMV(v) ((v).s0 + (v).s1)
#elif VW == 4
typedef float4 V;
#define SUMV(v) ((v).s0 + (v).s1 + (v).s2 + (v).s3)
#elif VW == 8
typedef float8 V;
#define SUMV(v) (SUM4((v).lo) + SUM4((v).hi))
#elif VW == 16
typedef float16 V;
#define SUMV(v) (SUM4((v).lo.lo) + SUM4((v).lo.hi) + SUM4((v).hi.lo) + SUM4((v).hi.hi))
#else
#error "VW must be 1, 2, 4, 8 or 16"
#endif
#define SUM4(v) ((v).s0 + (v).s1 + (v).s2 + (v).s3)

/* One step of every chain; the chains are independent of each other. */
#if CHAINS == 1
#define STEP x0 = x0 * m + c;
#elif CHAINS == 2
#define STEP x0 = x0 * m + c; x1 = x1 * m + c;
#elif CHAINS == 4
#define STEP x0 = x0 * m + c; x1 = x1 * m + c; x2 = x2 * m + c; x3 = x3 * m + c;
#else
#define STEP x0 = x0 * m + c; x1 = x1 * m + c; x2 = x2 * m + c; x3 = x3 * m + c; \
             x4 = x4 * m + c; x5 = x5 * m + c; x6 = x6 * m + c; x7 = x7 * m + c;
#endif
#if CHAINS != 1 && CHAINS != 2 && CHAINS != 4 && CHAINS != 8
#error "CHAINS must be 1, 2, 4 or 8"
#endif

/* FLOPs per work-item: iters * REPEAT * CHAINS * VW * 2. */
/** @param[out] out    [global size] one float per work-item (keeps the chains live)
 *  @param[in]  m      the multiplier of each FMA
 *  @param[in]  c      the addend
 *  @param[in]  iters  loop iterations
 *  @note -DVW=1|2|4|8|16: vector width; -DCHAINS=1|2|4|8: independent chains; -DREPEAT=n: FMAs per chain per iteration
 */
__kernel void fma_peak(__global float *out, float m, float c, int iters)
{
    const int gid = get_global_id(0);
    /* Distinct start values per chain and work-item: no two lanes compute the same thing. */
    const V base = (V)((float)gid * 1e-7f);
    V x0 = base + (V)0.1f, x1 = base + (V)0.2f, x2 = base + (V)0.3f, x3 = base + (V)0.4f;
    V x4 = base + (V)0.5f, x5 = base + (V)0.6f, x6 = base + (V)0.7f, x7 = base + (V)0.8f;
    for (int i = 0; i < iters; i++) {
#pragma unroll
        for (int r = 0; r < REPEAT; r++) {
            STEP
        }
    }
    out[gid] = SUMV(x0 + x1 + x2 + x3 + x4 + x5 + x6 + x7);
}

/* Stream kernels (McCalpin's STREAM, float4 per work-item): bytes moved per
 * element are counted as STREAM does (copy 2, triad 3 accesses; no write-allocate). */
/** @param[in]  a   [n4] source
 *  @param[out] c   [n4] destination
 *  @param[in]  n4  float4 elements
 */
__kernel void stream_copy(__global const float4 *a, __global float4 *c, int n4)
{
    const int i = get_global_id(0);
    if (i >= n4) return;
    c[i] = a[i];
}

/** @param[out] a   [n4] a = b + s * c
 *  @param[in]  b   [n4]
 *  @param[in]  c   [n4]
 *  @param[in]  s   the scalar
 *  @param[in]  n4  float4 elements
 */
__kernel void stream_triad(__global float4 *a, __global const float4 *b,
                           __global const float4 *c, float s, int n4)
{
    const int i = get_global_id(0);
    if (i >= n4) return;
    a[i] = b[i] + s * c[i];   /* contracted to an FMA; mad() is a slow call on PoCL */
}
