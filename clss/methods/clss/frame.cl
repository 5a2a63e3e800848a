/* The CLSS frame step, fused (clss/methods/clss/reference.md gives every formula; the
 * section numbers below are its sections).
 *
 *   clear                     zeroes the depth reconstruction and the flags
 *   prepare      render res   entry conversions, validity flags, transfer function,
 *                             dilation (s2), scatter of the previous depth (s3)
 *   depth_diff   render res   bilinear of the reconstructed depth -> dd, and dd less
 *                             the local depth slope's tolerance for the test (s4); the clamp
 *                             box of the encoded colour over 3x3 (s9); net mode: the
 *                             classifier's four measurements of the pixel's own depth and
 *                             motion against the previous frame's colour and depth (s4b),
 *                             and that state for the next frame
 *   resolve      output res   jitter-aware upsampling (s5), the 16-channel history warp
 *                             (s6), the history clip (s9); rule mode: ghost test, aux
 *                             update and blend (s8, s9) in the same pass; net mode: the
 *                             classifier input, padded to multiples of 16 by edge
 *                             replication (s7; the measurements at the render pixel
 *                             holding each output pixel's centre, s4b), and the
 *                             clipped history for compose
 *   compose      output res   net mode: logits x2 (s7), aux update (s8), composition
 *                             MLP and blend (s9)
 *
 * Build options:
 *   -DCLSS_FP16=1   half storage for the encoded colour, history, classifier input,
 *                   aux and logits (common.h); coordinates, depth and the render-res
 *                   stack stay float (they are positions and depth tests)
 *   -DHDR=0|1       PQ transfer (1) or clamp to [0, 1] (LDR in, LDR out)
 *   -DNET=0|1       resolve: rule mode (0) or classifier input (1)
 *   -DSANITIZE=0|1  replace non-finite inputs instead of refusing the frame
 *   -DHIDDEN=n      compose: hidden width of the composition MLP
 *   -DRULES_BASE=0|1 compose (net): the paper's blend (0: the MLP's weight, the classifier's
 *                   visibility decision) or the rules' base (1: clss-rules' decision and
 *                   weight 1/(1+n), which the MLP corrects as sigmoid(z - ln n); s9)
 *   -DCLIP_EPS=x    resolve: contract.RULE_CLIP_EPS, see the history clip (s9)
 *   -DCLIP_GAMMA=x  depth_diff: contract.CLIP_GAMMA, the clamp box's std multiple (s9)
 *   -DKNEE_TDD=x -DKNEE_CC=x -DKNEE_EDGE=x -DKNEE_SPREAD=x  depth_diff (net):
 *                   contract.MEASURE_KNEES, the measurements' compression v / (|v| + k)
 *   -DCLSS_CLANG_VECTORS=0|1  half loads/stores (LDV/STV, st_plane, neighbourhood
 *                   reads) through common.h's FLD/FLD8/FST/FST8, inline clang vector
 *                   conversions, instead of vload_halfN and vstore_halfN (out-of-line calls
 *                   on PoCL); 0 is the reference
 *   -DVEC=8|4|1     output-res pixels per work-item in resolve (rule) and compose
 *
 * Buffers: inputs in image layout (colour h x w x 3, motion h x w x 2 interleaved,
 * depth and reactive h x w), float. Planes ("NCHW") everywhere else. The output is
 * h x w x 3 interleaved float, linear, as the caller wants it.
 *
 * Debug views (debug != 0): dbg gets 3 output-res planes: blend weight, ghost (history
 * rejected), depth difference.
 *
 * Refused frames: `prepare` ORs what it finds into flags[0]; every later kernel reads
 * it and, if the frame is refused, copies the history through unchanged, so one bad
 * frame can never reach the state even though the host learns of it asynchronously.
 *
 * Every multiply-add is written in the oracle's (onnxruntime's) evaluation order and
 * FP_CONTRACT is off, so that fp32 matches the oracle to rounding and the exact
 * stages (dilation, scatter, validity, tap indices) match bit for bit.
 */
#include "common.h"
#pragma OPENCL FP_CONTRACT OFF

#ifndef HDR
#define HDR 1
#endif
#ifndef NET
#define NET 0
#endif
#ifndef SANITIZE
#define SANITIZE 0
#endif
#ifndef HIDDEN
#define HIDDEN 32
#endif
#ifndef RULES_BASE
#define RULES_BASE 0
#endif
/* hidden units of the composition MLP per pass over its inputs (compose) */
#define MLP_KB (HIDDEN % 4 == 0 ? 4 : 1)
#ifndef CLIP_EPS
#define CLIP_EPS 0.0019550342f
#endif
#ifndef CLIP_GAMMA
#define CLIP_GAMMA 1.25f
#endif
/* auto-reactive (contract.AUTO_REACTIVE_LO / _SLOPE / _MAX); AR_MAX 0 turns it off */
#ifndef AR_LO
#define AR_LO 0.05f
#endif
#ifndef AR_SLOPE
#define AR_SLOPE 8.0f
#endif
#ifndef AR_MAX
#define AR_MAX 0.5f
#endif
/* the classifier's measurements (s4b): v / (|v| + knee), contract.MEASURE_KNEES */
#ifndef KNEE_TDD
#define KNEE_TDD 0.05f
#endif
#ifndef KNEE_CC
#define KNEE_CC 0.02f
#endif
#ifndef KNEE_EDGE
#define KNEE_EDGE 0.1f
#endif
#ifndef KNEE_SPREAD
#define KNEE_SPREAD 0.02f
#endif

/* flags[0]: what was found (bits); flags[1..4]: non-finite element counts */
#define F_COLOR_NONFINITE 1u
#define F_DEPTH_NONFINITE 2u
#define F_MOTION_NONFINITE 4u
#define F_REACTIVE_NONFINITE 8u
#define F_DEPTH_RANGE 16u
#define F_REACTIVE_RANGE 32u
#if SANITIZE
#define F_REFUSE (F_DEPTH_RANGE | F_REACTIVE_RANGE)
#else
#define F_REFUSE 63u
#endif

/* render-res stack channels (the oracle's `aux` concat order) */
#define L_DEPTH 0
#define L_MX 1
#define L_MY 2
#define L_DD 3
#define L_REACTIVE 4
/* the depth test's own difference: dd less depth_slope x the local depth step (s4) */
#define L_DDT 5
#define L_NMIN 6
#define L_NMAX 9
/* net mode only (L_CHANNELS 19): the classifier's measurements (s4b), in
 * CLASSIFIER_INPUTS order: previous-depth difference, colour change, depth edge, colour
 * spread; then the pixel's own (entry-converted, not dilated) depth and motion x, y,
 * which prepare writes for them */
#define L_MEASURE 12
#define MEASURES 4
#define L_RAW_DEPTH 16
#define L_RAW_MX 17
#define L_RAW_MY 18

/* The buffer widths come from the host, where they are defined once: L_CHANNELS and HIST
 * from frame.py and contract.py, CLS_IN and COMP_IN from networks.py's channel layouts. */
#if !defined(L_CHANNELS) || !defined(HIST) || !defined(CLS_IN) || !defined(COMP_IN)
#error "frame.cl: build with -DL_CHANNELS -DHIST -DCLS_IN -DCOMP_IN (clss/methods/clss/frame.py)"
#endif

#include "pq.h"

/* The output-res arithmetic (aux update, MLP, blend, transfer function) runs on VEC
 * consecutive pixels of a row per work-item as explicit vectors: PoCL's CPU device then
 * vectorises it, exp2/log2 included (6x faster than what its implicit vectoriser makes
 * of the per-pixel form). VEC = 1 for GPUs, where each work-item is already a lane. */
#ifndef VEC
#define VEC 8
#endif
#if VEC == 8
typedef float8 fv;
typedef int8 iv;
#define VLD(p) vload8(0, (p))
#define VST(v, p) vstore8((v), 0, (p))
#define LDV(p, i) FLD8(p, i)
#define STV(p, i, v) FST8(p, i, v)
#elif VEC == 4
typedef float4 fv;
typedef int4 iv;
#define VLD(p) vload4(0, (p))
#define VST(v, p) vstore4((v), 0, (p))
#define LDV(p, i) LD4(p, i)
#define STV(p, i, v) ST4(p, i, v)
#elif VEC == 1
typedef float fv;
typedef int iv;
#define VLD(p) ((p)[0])
#define VST(v, p) ((p)[0] = (v))
#define LDV(p, i) FLD(p, i)
#define STV(p, i, v) FST(p, i, v)
#else
#error "VEC must be 1, 4 or 8"
#endif
#define FV(x) ((fv)(x))
#define LDF(p, i) ((p)[(i)])
#if VEC == 8
#define LANES ((iv)(0, 1, 2, 3, 4, 5, 6, 7))
#define CONVERT_IV convert_int8
#define CONVERT_FV convert_float8
#define ANY(m) any(m)
/* VEC loads at the lanes' indices */
#define GATHER(LDX, p, i) ((fv)(LDX(p, (i).s0), LDX(p, (i).s1), LDX(p, (i).s2), LDX(p, (i).s3), \
                                LDX(p, (i).s4), LDX(p, (i).s5), LDX(p, (i).s6), LDX(p, (i).s7)))
#elif VEC == 4
#define LANES ((iv)(0, 1, 2, 3))
#define CONVERT_IV convert_int4
#define CONVERT_FV convert_float4
#define ANY(m) any(m)
#define GATHER(LDX, p, i) ((fv)(LDX(p, (i).s0), LDX(p, (i).s1), LDX(p, (i).s2), LDX(p, (i).s3)))
#else
#define LANES 0
#define CONVERT_IV convert_int
#define CONVERT_FV convert_float
/* scalar comparisons give 1, vector ones -1: any() reads the sign bit */
#define ANY(m) (m)
#define GATHER(LDX, p, i) LDX(p, i)
#endif

/* -DCLSS_INLINE_MATH=1 (fast paths frame.inline_math.rule and .net; PoCL, whose compiler is
 * clang): the builtins these kernels call as plain operators and clang's vector conversions,
 * which compile inline. Pip's PoCL 3.0 calls fmin, fmax, fabs, clamp, floor, select, min,
 * max, any, vload2/3 and the vector convert, load and store builtins out of line
 * (inline_math.h says why), and a call spills every live vector register: depth_diff made
 * about 100 calls per pixel. clamp is fmin(fmax(x, lo), hi) as OpenCL defines it, select
 * is the vector ?: (the sign bit of each lane), isfinite is x - x == 0: the same results
 * for the values these kernels see. sqrt and the atomics stay the builtins (oclgrind runs
 * neither llvm's sqrt nor atomicrmw). The PQ transfer takes pq.h's powq8 and the
 * composition's sigmoid pq_exp2q8 (VEC = 8), which round differently from the library's
 * exp2, log2 and exp; everything else is bit-exact. =0: the builtins. */
#ifndef CLSS_INLINE_MATH
#define CLSS_INLINE_MATH 0
#endif
#if CLSS_INLINE_MATH
/* fmin_q, fmax_q, floor_q and fabs_q on float and its vectors: kernels/inline_math.h,
 * which tests/test_method_clss_frame.py checks under oclgrind in this variant too */
#include "inline_math.h"
#define FMIN fmin_q
#define FMAX fmax_q
#define FABS fabs_q
#define FLOOR floor_q
#define CLAMP(v, lo, hi) FMIN(FMAX((v), (lo)), (hi))
#define SELECT(a, b, c) ((c) ? (b) : (a))
#define IMIN(a, b) ((a) < (b) ? (a) : (b))
#define IMAX(a, b) ((a) > (b) ? (a) : (b))
#define SQRT sqrt
#define ISFINITE(x) ((x) - (x) == 0.0f)
#define VLOAD3(i, p) ((float3)((p)[3 * (i)], (p)[3 * (i) + 1], (p)[3 * (i) + 2]))
#define VLOAD2(i, p) ((float2)((p)[2 * (i)], (p)[2 * (i) + 1]))
#if VEC > 1
typedef float FrameVecP __attribute__((ext_vector_type(VEC), aligned(4)));
#undef VLD
#undef VST
#define VLD(p) ((fv)(*(__private const FrameVecP *)(p)))
#define VST(v, p) (*(__private FrameVecP *)(p) = (v))
#undef CONVERT_IV
#undef CONVERT_FV
#define CONVERT_IV(x) __builtin_convertvector((x), iv)
#define CONVERT_FV(x) __builtin_convertvector((x), fv)
#undef ANY
#if VEC == 8
#define ANY(m) any8(m)
static inline int any8(int8 m)
{
    const int4 a = m.lo | m.hi;
    const int2 b = a.lo | a.hi;
    return (b.x | b.y) < 0;
}
#else
#define ANY(m) any4(m)
static inline int any4(int4 m)
{
    const int2 b = m.lo | m.hi;
    return (b.x | b.y) < 0;
}
#endif
#endif
#else
#define FMIN fmin
#define FMAX fmax
#define FABS fabs
#define FLOOR floor
#define CLAMP clamp
#define SELECT select
#define IMIN min
#define IMAX max
#define SQRT sqrt
#define ISFINITE isfinite
#define VLOAD3 vload3
#define VLOAD2 vload2
#endif
/* any lane of a float3 / float2 not finite */
#define NONFINITE3(c) (!(ISFINITE((c).x) && ISFINITE((c).y) && ISFINITE((c).z)))
#define NONFINITE2(c) (!(ISFINITE((c).x) && ISFINITE((c).y)))

/* x^y for x >= 0 as exp2(y log2 x): 4-5x faster than pow on PoCL's CPU device, about
 * 1e-5 relative here (the transfer function is the hot spot at output resolution);
 * 0 stays 0 (log2 0 = -inf). */
#define POWP(x, y) exp2((y) * log2(x))
#if CLSS_INLINE_MATH && VEC == 8
#define POWQ powq8
#define EXPV(x) pq_exp2q8((x) * 1.44269504088896341f)
#else
#define POWQ POWP
#define EXPV exp
#endif

/* The transfer on VEC pixels: pq.h's PQ (inv_pq_scale = 10000 / nits), or a clamp. */
#if HDR
inline PQ_ENCODE(fv, encode, POWP)
inline PQ_DECODE(fv, decode, POWP, fmax, clamp)
#else
inline fv encode(fv x, float pq_scale)
{
    return CLAMP(x, 0.0f, 1.0f);
}

inline fv decode(fv e, float inv_pq_scale)
{
    return e;
}
#endif

/* v (VEC pixels) to plane p at q .. q + n - 1; n < VEC at the right edge of a row. */
inline void st_plane(__global T *p, int q, fv v, int n)
{
    if (n == VEC) {
        STV(p, q, v);
        return;
    }
    float t[VEC];
    VST(v, t);
    for (int l = 0; l < n; ++l)
        FST(p, q + l, t[l]);
}

inline void st_plane_f(__global float *p, int q, fv v, int n)
{
    float t[VEC];
    VST(v, t);
    for (int l = 0; l < n; ++l)
        p[q + l] = t[l];
}

/* The linear output, interleaved h x w x 3 as the caller wants it. */
inline void st_rgb(__global float *out, int q, fv r, fv g, fv b, int n)
{
    float t[3][VEC];
    VST(r, t[0]);
    VST(g, t[1]);
    VST(b, t[2]);
    for (int l = 0; l < n; ++l) {
        out[(q + l) * 3] = t[0][l];
        out[(q + l) * 3 + 1] = t[1][l];
        out[(q + l) * 3 + 2] = t[2][l];
    }
}

/* Entry conversions (reference.md s1), applied on every load so that neighbours read
 * the same values as the centre. A non-finite value is either flagged (and the frame
 * refused) or, with SANITIZE, replaced: colour 0, depth far, motion 0. */
inline float ld_depth(__global const float *depth, int i, int inverted)
{
    float d = depth[i];
#if SANITIZE
    if (!ISFINITE(d)) return 0.0f;
#endif
    return inverted ? d : 1.0f - d;
}

inline float2 ld_motion(__global const float *motion, int i, float2 ms)
{
    float2 m = VLOAD2(i, motion);
#if SANITIZE
    m = SELECT(m, (float2)(0.0f), ISFINITE(m) == (int2)(0));
#endif
    return (ms.x == 1.0f && ms.y == 1.0f) ? m : m * ms;
}

inline float3 ld_color(__global const float *color, int i, float inv_exposure)
{
    float3 c = VLOAD3(i, color);
#if SANITIZE
    c = SELECT(c, (float3)(0.0f), ISFINITE(c) == (int3)(0));
#endif
    return inv_exposure == 1.0f ? c : c * inv_exposure;
}

/* Taps and weights along one axis for VEC positions (border padding: taps clamp to
 * the edge). Rows are pre-multiplied by the row length. */
typedef struct {
    iv c0, c1, c2, c3;
    fv w0, w1, w2, w3;
} Taps4;                /* bicubic */

typedef struct {
    iv c0, c1;
    fv w0, w1;
} Taps2;                /* bilinear */

inline int edge(float t, int n)
{
    return (int)FMIN(FMAX(t, 0.0f), (float)(n - 1));
}

inline iv edge_v(fv t, int n)
{
    return CONVERT_IV(FMIN(FMAX(t, 0.0f), (float)(n - 1)));
}

/* Keys cubic weights (a = -0.75) for the taps at -1, 0, 1, 2 around u, in onnxruntime's
 * GsGetCubicCoeffs form. */
inline Taps4 cubic_taps(fv u, int n, int stride)
{
    Taps4 t;
    const fv f = FLOOR(u), x = FABS(u - f);
    const float a = -0.75f;
    t.c0 = edge_v(f - 1.0f, n) * stride;
    t.c1 = edge_v(f, n) * stride;
    t.c2 = edge_v(f + 1.0f, n) * stride;
    t.c3 = edge_v(f + 2.0f, n) * stride;
    t.w0 = ((a * (x + 1.0f) - 5.0f * a) * (x + 1.0f) + 8.0f * a) * (x + 1.0f) - 4.0f * a;
    t.w1 = ((a + 2.0f) * x - (a + 3.0f)) * x * x + 1.0f;
    t.w2 = ((a + 2.0f) * (1.0f - x) - (a + 3.0f)) * (1.0f - x) * (1.0f - x) + 1.0f;
    t.w3 = ((a * (2.0f - x) - 5.0f * a) * (2.0f - x) + 8.0f * a) * (2.0f - x) - 4.0f * a;
    return t;
}

/* onnxruntime's bilinear weights: w0 = x1 + 1 - u for tap x1 = floor(u), w1 = u - x1 */
inline Taps2 linear_taps(fv u, int n, int stride)
{
    Taps2 t;
    const fv f = FLOOR(u);
    t.c0 = edge_v(f, n) * stride;
    t.c1 = edge_v(f + 1.0f, n) * stride;
    t.w0 = (f + 1.0f) - u;
    t.w1 = u - f;
    return t;
}

/* The oracle feeds GridSample the normalised coordinate (2u + 1) / n - 1, which
 * onnxruntime maps back with ((g + 1) n - 1) / 2; doing the same round trip here puts
 * every tap exactly where the oracle's is (the two can differ by an ulp of u). */
inline fv grid_round_trip(fv u, int n)
{
    const float fn = (float)n;
    const fv g = (u * 2.0f + 1.0f) / fn - 1.0f;
    return ((g + 1.0f) * fn - 1.0f) / 2.0f;
}

/* One channel sampled at VEC positions: rows first (x), then along y, the oracle's
 * order. The loads are gathers; the arithmetic runs on vectors. */
inline fv cubic_T(__global const T *p, Taps4 x, Taps4 y)
{
#define ROW(r) (x.w0 * GATHER(FLD, p, (r) + x.c0) + x.w1 * GATHER(FLD, p, (r) + x.c1) + \
                x.w2 * GATHER(FLD, p, (r) + x.c2) + x.w3 * GATHER(FLD, p, (r) + x.c3))
    return y.w0 * ROW(y.c0) + y.w1 * ROW(y.c1) + y.w2 * ROW(y.c2) + y.w3 * ROW(y.c3);
#undef ROW
}

#define LINEAR_SAMPLER(name, ELEM, LDX)                                                      \
    inline fv name(__global const ELEM *p, Taps2 x, Taps2 y)                                \
    {                                                                                        \
        return y.w0 * (x.w0 * GATHER(LDX, p, y.c0 + x.c0) + x.w1 * GATHER(LDX, p, y.c0 + x.c1)) + \
               y.w1 * (x.w0 * GATHER(LDX, p, y.c1 + x.c0) + x.w1 * GATHER(LDX, p, y.c1 + x.c1)); \
    }
LINEAR_SAMPLER(linear_T, T, FLD)
LINEAR_SAMPLER(linear_f, float, LDF)

/* Windows (CLSS_INLINE_MATH at VEC = 8, clang): where a work-item's 8 lanes read taps that
 * lie in one run of a row, each tap's 8 values are one vector load (the history at P +
 * motion: lane e at b + e + k for tap k, wherever the motion is smooth) or lanes of one
 * loaded window spread by a shuffle (the render-res planes at 2x, and compose's logits
 * from half resolution: lane e at b + o_e + k,
 * o = (0, 0, 1, 1, 2, 2, 3, 3) or (0, 1, 1, 2, 2, 3, 3, 4) by the jitter's fraction), instead
 * of 8 scalar loads; checked per work-item on the taps themselves (every lane's tap index
 * is the run's, none clamped, the rows one for all lanes), so the same elements are read
 * and summed in the same order: bit-exact. Elsewhere (the edges, a motion edge within the
 * 8 pixels, other scales) the gathers. */
#if CLSS_INLINE_MATH && VEC == 8 && defined(__clang__)
#define WIN8 1
#define SHUF8(v, a, b, c, d, e, f, g, h) __builtin_shufflevector((v), (v), a, b, c, d, e, f, g, h)
#define PAT_A(v, k) SHUF8(v, 0 + k, 0 + k, 1 + k, 1 + k, 2 + k, 2 + k, 3 + k, 3 + k)
#define PAT_B(v, k) SHUF8(v, 0 + k, 1 + k, 1 + k, 2 + k, 2 + k, 3 + k, 3 + k, 4 + k)
#define PAT_OFFS_A ((iv)(0, 0, 1, 1, 2, 2, 3, 3))
#define PAT_OFFS_B ((iv)(0, 1, 1, 2, 2, 3, 3, 4))

/* 1: the 8 lanes' taps are b + LANES + k (k = 0..NT-1), rows one for all lanes */
inline int run_taps4(Taps4 x, Taps4 y)
{
    const iv s = x.c0.s0 + LANES;
    return !ANY((x.c0 != s) | (x.c1 != s + 1) | (x.c2 != s + 2) | (x.c3 != s + 3) |
                (y.c0 != y.c0.s0) | (y.c1 != y.c1.s0) | (y.c2 != y.c2.s0) | (y.c3 != y.c3.s0));
}

inline int run_taps2(Taps2 x, Taps2 y)
{
    const iv s = x.c0.s0 + LANES;
    return !ANY((x.c0 != s) | (x.c1 != s + 1) | (y.c0 != y.c0.s0) | (y.c1 != y.c1.s0));
}

/* the render-res pattern of x (cubic taps at 2x): 1 (A), 2 (B) or 0 (gathers), for a
 * window of 8 from x.c0.s0 inside the row of n */
inline int pat_taps4(Taps4 x, int n)
{
    const int b = x.c0.s0;
    if (b + 8 > n || ANY((x.c1 != x.c0 + 1) | (x.c2 != x.c0 + 2) | (x.c3 != x.c0 + 3)))
        return 0;
    const iv o = x.c0 - b;
    return !ANY(o != PAT_OFFS_A) ? 1 : (!ANY(o != PAT_OFFS_B) ? 2 : 0);
}

/* cubic_T with the history's runs: lane e of tap k at row + b + e + k */
inline fv cubic_T_run(__global const T *p, Taps4 x, Taps4 y)
{
    const int b = x.c0.s0;
#define ROWR(r) (x.w0 * FLD8(p, (r) + b) + x.w1 * FLD8(p, (r) + b + 1) + \
                 x.w2 * FLD8(p, (r) + b + 2) + x.w3 * FLD8(p, (r) + b + 3))
    return y.w0 * ROWR(y.c0.s0) + y.w1 * ROWR(y.c1.s0) + y.w2 * ROWR(y.c2.s0) + y.w3 * ROWR(y.c3.s0);
#undef ROWR
}

inline fv linear_T_run(__global const T *p, Taps2 x, Taps2 y)
{
    const int b = x.c0.s0;
    return y.w0 * (x.w0 * FLD8(p, y.c0.s0 + b) + x.w1 * FLD8(p, y.c0.s0 + b + 1)) +
           y.w1 * (x.w0 * FLD8(p, y.c1.s0 + b) + x.w1 * FLD8(p, y.c1.s0 + b + 1));
}

/* cubic_T and linear over the render-res windows: pat 1 (A) or 2 (B) from pat_taps4; the
 * linear taps are the cubic's c1 and c2 (the same floor of the same coordinate) */
#define CUBIC_ROW_P(P, v, x) (x.w0 * P(v, 0) + x.w1 * P(v, 1) + x.w2 * P(v, 2) + x.w3 * P(v, 3))
inline fv cubic_T_pat(__global const T *p, Taps4 x, Taps4 y, int pat)
{
    const int b = x.c0.s0;
    const fv r0 = FLD8(p, y.c0.s0 + b), r1 = FLD8(p, y.c1.s0 + b), r2 = FLD8(p, y.c2.s0 + b),
             r3 = FLD8(p, y.c3.s0 + b);
    if (pat == 1)
        return y.w0 * CUBIC_ROW_P(PAT_A, r0, x) + y.w1 * CUBIC_ROW_P(PAT_A, r1, x) +
               y.w2 * CUBIC_ROW_P(PAT_A, r2, x) + y.w3 * CUBIC_ROW_P(PAT_A, r3, x);
    return y.w0 * CUBIC_ROW_P(PAT_B, r0, x) + y.w1 * CUBIC_ROW_P(PAT_B, r1, x) +
           y.w2 * CUBIC_ROW_P(PAT_B, r2, x) + y.w3 * CUBIC_ROW_P(PAT_B, r3, x);
}

/* the pattern of linear taps (compose's logits, 2x from half resolution): as pat_taps4 */
inline int pat_taps2(Taps2 x, int n)
{
    const int b = x.c0.s0;
    if (b + 8 > n || ANY(x.c1 != x.c0 + 1))
        return 0;
    const iv o = x.c0 - b;
    return !ANY(o != PAT_OFFS_A) ? 1 : (!ANY(o != PAT_OFFS_B) ? 2 : 0);
}

inline fv linear_T_pat(__global const T *p, Taps2 x, Taps2 y, int pat)
{
    const int b = x.c0.s0;
    const fv r0 = FLD8(p, y.c0.s0 + b), r1 = FLD8(p, y.c1.s0 + b);
    if (pat == 1)
        return y.w0 * (x.w0 * PAT_A(r0, 0) + x.w1 * PAT_A(r0, 1)) +
               y.w1 * (x.w0 * PAT_A(r1, 0) + x.w1 * PAT_A(r1, 1));
    return y.w0 * (x.w0 * PAT_B(r0, 0) + x.w1 * PAT_B(r0, 1)) +
           y.w1 * (x.w0 * PAT_B(r1, 0) + x.w1 * PAT_B(r1, 1));
}

/* b: the cubic's x.c0.s0 (the window's start); x, y: the linear taps */
inline fv linear_f_pat(__global const float *p, int b, Taps2 x, Taps2 y, int pat)
{
    const fv r0 = XLD8(p + y.c0.s0 + b), r1 = XLD8(p + y.c1.s0 + b);
    if (pat == 1)
        return y.w0 * (x.w0 * PAT_A(r0, 1) + x.w1 * PAT_A(r0, 2)) +
               y.w1 * (x.w0 * PAT_A(r1, 1) + x.w1 * PAT_A(r1, 2));
    return y.w0 * (x.w0 * PAT_B(r0, 1) + x.w1 * PAT_B(r0, 2)) +
           y.w1 * (x.w0 * PAT_B(r1, 1) + x.w1 * PAT_B(r1, 2));
}
#else
#define WIN8 0
#endif

/* The 4 bilinear taps of p + motion for the depth reconstruction (reference.md s3):
 * tap k = (a, b) in order (0,0) (1,0) (0,1) (1,1). */
#define SCATTER_TAPS(j, i, m)                                             \
    const float ux = (float)(j) + (m).x, uy = (float)(i) + (m).y;         \
    const float x0 = FLOOR(ux), y0 = FLOOR(uy);                           \
    const float fx = ux - x0, fy = uy - y0;                               \
    const float wxs[2] = {1.0f - fx, fx}, wys[2] = {1.0f - fy, fy};

/* Zeroes a[0, na) and b[0, nb) (32-bit words): the depth reconstruction and the flags
 * before each frame, the history once. (A kernel rather than clEnqueueFillBuffer, which
 * oclgrind's uninitialised-memory check does not see.) */
/** @param[out] a   [na] 32-bit words set to 0
 *  @param[in]  na  words of a
 *  @param[out] b   [nb] 32-bit words set to 0
 *  @param[in]  nb  words of b
 */
__kernel void clear(__global uint *a, int na, __global uint *b, int nb)
{
    const int i = get_global_id(0);
    if (i < na) a[i] = 0u;
    if (i < nb) b[i] = 0u;
}

/* Stage 1 (dilate) + stage 2 (scatter), the encoded colour and the input checks, in one
 * pass over the render-res inputs; VEC pixels of a row per work-item (the transfer
 * function runs on them as a vector).
 * recon: h*w uint, cleared to 0 (far) before this kernel; X: 3 planes T; lr: stack. */
/** @param[in]  color         h x w x 3 float, image layout
 *  @param[in]  depth         h x w float
 *  @param[in]  motion        h x w x 2 float, render pixels
 *  @param[in]  reactive      h x w float (any valid buffer when has_reactive = 0)
 *  @param[in]  has_reactive  1 if reactive holds the caller's mask, else 0 (read as 0)
 *  @param[in]  w, h          render width and height
 *  @param[in]  depth_inverted 1: reversed-Z input (near = 1), 0: standard Z (converted)
 *  @param[in]  msx, msy      motion_scale (render pixels per motion unit)
 *  @param[in]  inv_exposure  1 / exposure
 *  @param[in]  pq_scale      nits / 10000 (linear 1.0 in PQ's units)
 *  @param[out] recon         [h*w] uint previous-depth reconstruction (s3), cleared beforehand
 *  @param[out] X             [3, h, w] T the encoded colour
 *  @param[out] lr            [L_CHANNELS, h, w] float the render-res stack: dilated depth, motion, ... (net: and the pixel's own depth and motion, s4b)
 *  @param[out] flags         [8] uint: flags[0] |= what was found, flags[1..4] non-finite counts
 *  @note -DHDR=0|1: PQ or clamp; -DSANITIZE=0|1: replace non-finite inputs or refuse; -DVEC=8|4|1: pixels per work-item
 *  @note -DCLSS_FP16=1: X in half (T)
 */
__kernel void prepare(__global const float *color, __global const float *depth,
                      __global const float *motion, __global const float *reactive,
                      int has_reactive, int w, int h, int depth_inverted, float msx, float msy,
                      float inv_exposure, float pq_scale,
                      __global uint *recon, __global T *X, __global float *lr,
                      __global uint *flags)
{
    const int j0 = get_global_id(0) * VEC, i = get_global_id(1);
    if (j0 >= w || i >= h) return;
    const int hw = w * h, n = IMIN(VEC, w - j0);
    const float2 ms = (float2)(msx, msy);
    /* the colour of the VEC pixels, gathered for the vector transfer function */
    float cr[VEC], cg[VEC], cb[VEC];
    for (int l = 0; l < VEC; ++l) {
        const int j = IMIN(j0 + l, w - 1), p = i * w + j;
        const float3 c = ld_color(color, p, inv_exposure);
        cr[l] = c.x;
        cg[l] = c.y;
        cb[l] = c.z;
        if (l >= n) continue;       /* past the row's end: only the colour, for the vector */

        /* input checks on this pixel's own values */
        uint bad = 0;
        const float3 c_raw = VLOAD3(p, color);
        const float d_raw = depth[p];
        const float2 m_raw = VLOAD2(p, motion);
        if (NONFINITE3(c_raw)) bad |= F_COLOR_NONFINITE;
        if (!ISFINITE(d_raw)) bad |= F_DEPTH_NONFINITE;
        else if (!(d_raw >= 0.0f && d_raw <= 1.0f)) bad |= F_DEPTH_RANGE;
        if (NONFINITE2(m_raw)) bad |= F_MOTION_NONFINITE;
        float r = 0.0f;
        if (has_reactive) {
            r = reactive[p];
            if (!ISFINITE(r)) {
                bad |= F_REACTIVE_NONFINITE;
#if SANITIZE
                r = 0.0f;
#endif
            } else if (!(r >= 0.0f && r <= 1.0f)) {
                bad |= F_REACTIVE_RANGE;
            }
        }
        if (bad) {
            atomic_or(flags, bad);
            /* element counts, for the report of what SANITIZE replaced */
            if (bad & F_COLOR_NONFINITE)
                atomic_add(flags + 1, (uint)(!ISFINITE(c_raw.x) + !ISFINITE(c_raw.y) + !ISFINITE(c_raw.z)));
            if (bad & F_DEPTH_NONFINITE) atomic_inc(flags + 2);
            if (bad & F_MOTION_NONFINITE) atomic_add(flags + 3, (uint)(!ISFINITE(m_raw.x) + !ISFINITE(m_raw.y)));
            if (bad & F_REACTIVE_NONFINITE) atomic_inc(flags + 4);
        }

        /* s2: the first neighbour with the nearest (largest) depth, FSR2's order; the
         * centre comes first so it wins ties. */
        const int2 offs[9] = {(int2)(0, 0), (int2)(1, 0), (int2)(0, 1), (int2)(0, -1), (int2)(-1, 0),
                              (int2)(-1, 1), (int2)(1, 1), (int2)(-1, -1), (int2)(1, -1)};
        const float d_own = ld_depth(depth, p, depth_inverted);
        float best = d_own;
        int bi = p;
        for (int k = 1; k < 9; ++k) {
            const int jj = j + offs[k].x, ii = i + offs[k].y;
            if (jj < 0 || jj >= w || ii < 0 || ii >= h) continue;
            const float d = ld_depth(depth, ii * w + jj, depth_inverted);
            if (d > best) { best = d; bi = ii * w + jj; }
        }
        const float2 m = ld_motion(motion, bi, ms);
        lr[L_DEPTH * hw + p] = best;
        lr[L_MX * hw + p] = m.x;
        lr[L_MY * hw + p] = m.y;
        lr[L_REACTIVE * hw + p] = r;
#if NET
        /* s4b: the measurements read the pixel's own depth and motion, not the dilated
         * ones (dilation gives a strip revealed behind a moving edge the edge's) */
        {
            const float2 m_own = bi == p ? m : ld_motion(motion, p, ms);
            lr[L_RAW_DEPTH * hw + p] = d_own;
            lr[L_RAW_MX * hw + p] = m_own.x;
            lr[L_RAW_MY * hw + p] = m_own.y;
        }
#endif

        /* s3: scatter-max of the dilated depth onto the previous frame's pixels. Depth is
         * >= 0, so its float bits order like the floats; the sign bit is cleared so that
         * -0.0 does not win over everything. */
        {
            SCATTER_TAPS(j, i, m)
            const uint bits = as_uint(best) & 0x7fffffffu;
            for (int b = 0; b < 2; ++b)
                for (int a = 0; a < 2; ++a) {
                    const float wk = wxs[a] * wys[b];
                    const float xk = x0 + (float)a, yk = y0 + (float)b;
                    if (xk >= 0.0f && xk <= (float)(w - 1) && yk >= 0.0f && yk <= (float)(h - 1) &&
                        wk > 0.01f)
                        atomic_max(recon + (int)yk * w + (int)xk, bits);
                }
        }
    }

    /* transfer function */
    const int p0 = i * w + j0;
    st_plane(X, p0, encode(VLD(cr), pq_scale), n);
    st_plane(X, hw + p0, encode(VLD(cg), pq_scale), n);
    st_plane(X, 2 * hw + p0, encode(VLD(cb), pq_scale), n);
}

/* Stage 3: the reconstructed previous depth read bilinearly at p + motion (taps that
 * were refused by the scatter are still read; off-screen taps read far). The clamp box
 * rides along: it needs the whole encoded colour, which only exists after `prepare`; so
 * do net mode's measurements (s4b), which need it and the 3x3 neighbourhood too. */
/** @param[in]     recon  [h*w] uint the reconstructed previous depth (prepare)
 *  @param[in]     X      [3, h, w] T the encoded colour (for the clamp box)
 *  @param[in,out] lr     the render-res stack: gets the depth difference, the depth test's difference and the clamp box (net: and the measurements, of the pixel's own depth and motion planes)
 *  @param[in]     w, h   render width and height
 *  @param[in]     depth_slope  the depth test's tolerance per unit of local relative depth step (contract.DEPTH_SLOPE; 0: the plain test)
 *  @param[in]     prev   net only: [4, h, w] float the previous accepted frame's encoded colour and own (not dilated) depth (not read on a reset)
 *  @param[out]    prev_out net only: [4, h, w] float this frame's, for the next one (the state once the frame is accepted)
 *  @param[in]     reset  net only: 1 on a camera cut or the first frame (the previous frame's measurements are 0)
 *  @note -DCLIP_GAMMA=x: the box's std multiple (contract.CLIP_GAMMA)
 *  @note -DNET=1: the measurements and the extra arguments; -DKNEE_TDD, _CC, _EDGE, _SPREAD (contract.MEASURE_KNEES)
 *  @note -DCLSS_FP16=1: X in half (T)
 */
__kernel void depth_diff(__global const uint *recon, __global const T *X, __global float *lr,
                         int w, int h, float depth_slope
#if NET
                         , __global const float *prev, __global float *prev_out, int reset
#endif
                         )
{
    const int j = get_global_id(0), i = get_global_id(1);
    if (j >= w || i >= h) return;
    const int p = i * w + j, hw = w * h;
    const float d = lr[L_DEPTH * hw + p];
    const float2 m = (float2)(lr[L_MX * hw + p], lr[L_MY * hw + p]);
    SCATTER_TAPS(j, i, m)
    float rs = 0.0f;
    for (int b = 0; b < 2; ++b)
        for (int a = 0; a < 2; ++a) {
            const float wk = wxs[a] * wys[b];
            const float xk = x0 + (float)a, yk = y0 + (float)b;
            const int on = xk >= 0.0f && xk <= (float)(w - 1) && yk >= 0.0f && yk <= (float)(h - 1);
            const float rk = on ? as_float(recon[edge(yk, h) * w + edge(xk, w)]) : 0.0f;
            rs = rs + rk * wk;
        }
    const float dd = CLAMP((rs - d) / FMAX(rs, 1e-6f), -1.0f, 1.0f);
    lr[L_DD * hw + p] = dd;
    /* the depth test's difference (reference.md s4): dd less depth_slope x the local
     * relative depth step, the smaller one-sided step in x plus that in y (edge pixels
     * repeat: a step of 0). A grazing floor steps steadily, so both sides are large and
     * its reprojection error passes; a silhouette is flat on one side and stays tested.
     * Only the dilated depth plane is read, which no work-item of this kernel writes. */
    {
        __global const float *D = lr + L_DEPTH * hw;
        const float l = D[i * w + IMAX(j - 1, 0)], r = D[i * w + IMIN(j + 1, w - 1)];
        const float u = D[IMAX(i - 1, 0) * w + j], b = D[IMIN(i + 1, h - 1) * w + j];
        const float sx = FMIN(FABS(r - d), FABS(d - l)), sy = FMIN(FABS(b - d), FABS(d - u));
        lr[L_DDT * hw + p] = dd - depth_slope * ((sx + sy) / FMAX(d, 1e-6f));
    }
    /* auto-reactive (contract.AUTO_REACTIVE_*): where the dilated motion of the 3x3
     * neighbourhood diverges, surfaces move apart and a warped history mixes them, so the
     * blend weight is raised as the caller's reactive mask would (in-bounds neighbours;
     * only the motion planes are read here, which no work-item of this kernel writes) */
#if NET
    /* s4b: the pixel's own depth and motion (prepare's planes, which no work-item of this
     * kernel writes); dmin, dmax: the own depth's 3x3 range */
    const float d_own = lr[L_RAW_DEPTH * hw + p];
    const float2 m_own = (float2)(lr[L_RAW_MX * hw + p], lr[L_RAW_MY * hw + p]);
    float dmin = d_own, dmax = d_own;
#endif
    {
        float div = 0.0f;
        for (int dy = -1; dy <= 1; ++dy) {
            const int ii = i + dy;
            if (ii < 0 || ii >= h) continue;
            for (int dx = -1; dx <= 1; ++dx) {
                const int jj = j + dx;
                if (jj < 0 || jj >= w) continue;
                const int pn = ii * w + jj;
                div = FMAX(div, FABS(lr[L_MX * hw + pn] - m.x) + FABS(lr[L_MY * hw + pn] - m.y));
#if NET
                const float dn = lr[L_RAW_DEPTH * hw + pn];
                dmin = FMIN(dmin, dn);
                dmax = FMAX(dmax, dn);
#endif
            }
        }
        lr[L_REACTIVE * hw + p] = FMAX(lr[L_REACTIVE * hw + p],
                                       CLAMP((div - AR_LO) * AR_SLOPE, 0.0f, AR_MAX));
    }

    /* the clamp box: min and max of the encoded colour over the 3x3 window, narrowed to
     * mean +- CLIP_GAMMA std (off-screen neighbours left out of all four). The moments
     * are taken of the differences to the centre pixel, in the oracle's order (rows,
     * then columns): E[x^2] - E[x]^2 of the values themselves cancels to the point where
     * float rounding moved the box by 1e-4. */
#if NET
    float spread = 0.0f;            /* the largest channel range of the window (s4b) */
#endif
    for (int c = 0; c < 3; ++c) {
        __global const T *x = X + c * hw;
        const float xc = FLD(x, p);
        float lo = xc, hi = xc, s1 = 0.0f, s2 = 0.0f, cnt = 0.0f;
        for (int dy = -1; dy <= 1; ++dy) {
            const int ii = i + dy;
            if (ii < 0 || ii >= h) continue;
            for (int dx = -1; dx <= 1; ++dx) {
                const int jj = j + dx;
                if (jj < 0 || jj >= w) continue;
                const float n = FLD(x, ii * w + jj);
                lo = FMIN(lo, n);
                hi = FMAX(hi, n);
                const float d = n - xc;
                s1 = s1 + d;
                s2 = s2 + d * d;
                cnt = cnt + 1.0f;
            }
        }
        const float md = s1 / cnt;
        const float sd = CLIP_GAMMA * SQRT(FMAX(s2 / cnt - md * md, 0.0f));
        const float mu = xc + md;
        lr[(L_NMIN + c) * hw + p] = FMAX(lo, mu - sd);
        lr[(L_NMAX + c) * hw + p] = FMIN(hi, mu + sd);
#if NET
        spread = FMAX(spread, hi - lo);
#endif
    }
#if NET
    /* s4b, the classifier's measurements: what the rule detectors look at, given to the
     * network rather than thresholded, of the pixel's own depth and motion. The previous
     * frame is read at the nearest pixel to p + motion (the tap rounded as the oracle and
     * the torch twin round it, so that all three read the same pixel); off screen there is
     * no previous frame, which counts as the largest change (1). A reset has none either,
     * but says nothing: 0. */
    float tdd = 0.0f, cc = 0.0f;
    if (!reset) {
        const float qx = FLOOR(((float)j + m_own.x) + 0.5f);
        const float qy = FLOOR(((float)i + m_own.y) + 0.5f);
        if (qx >= 0.0f && qx <= (float)(w - 1) && qy >= 0.0f && qy <= (float)(h - 1)) {
            const int q = (int)qy * w + (int)qx;
            const float pd = prev[3 * hw + q];
            tdd = CLAMP((pd - d_own) / FMAX(pd, 1e-6f), -1.0f, 1.0f);
            for (int c = 0; c < 3; ++c)
                cc = FMAX(cc, FABS(FLD(X + c * hw, p) - prev[c * hw + q]));
        } else {
            tdd = cc = 1.0f;
        }
    }
    const float edge = (dmax - dmin) / FMAX(dmax, 1e-6f);
    /* each compressed as v / (|v| + knee): the label-relevant sizes become O(1) and the
     * outliers (off screen, a full-range edge) stay below 1 */
    lr[L_MEASURE * hw + p] = tdd / (FABS(tdd) + KNEE_TDD);
    lr[(L_MEASURE + 1) * hw + p] = cc / (FABS(cc) + KNEE_CC);
    lr[(L_MEASURE + 2) * hw + p] = edge / (FABS(edge) + KNEE_EDGE);
    lr[(L_MEASURE + 3) * hw + p] = spread / (FABS(spread) + KNEE_SPREAD);
    /* the next frame's state: the colour as stored (half in fp16 storage, which float
     * holds exactly) and the pixel's own depth. Written on a reset too, and on a frame
     * that is then refused: the host only swaps the state in when it accepts the frame. */
    for (int c = 0; c < 3; ++c)
        prev_out[c * hw + p] = FLD(X + c * hw, p);
    prev_out[3 * hw + p] = d_own;
#endif
}

/* What stages 4 and 5 give VEC output pixels. */
typedef struct {
    fv up[3], col[3], mn[3], mx[3], lg[6];
    fv depth, mvx, mvy, dd, ddt, react, cnt;
    iv valid;
    fv bmin[3], bmax[3];
#if NET
    fv meas[MEASURES];      /* the classifier's measurements (s4b), nearest */
#endif
} Gathered;

/* Stages 4 and 5 at output pixels (I, J[lane]). bx, by: (J + 0.5) w / W - 0.5 per column
 * and row (float64 on the host, rounded, as the oracle's constants). */
inline Gathered gather(int I, iv J, __global const T *X, __global const float *lr,
                       __global const float *bx, __global const float *by, float jx, float jy,
                       int w, int h, int W, int H, float sx, float sy, int reset,
                       __global const T *hist)
{
    Gathered g;
    const int hw = w * h, HW = W * H;
    const fv u = grid_round_trip(CLAMP(GATHER(LDF, bx, J) - jx, 0.0f, (float)(w - 1)), w);
    const fv v = grid_round_trip(FV(CLAMP(by[I] - jy, 0.0f, (float)(h - 1))), h);
    const Taps4 cx = cubic_taps(u, w, 1), cy = cubic_taps(v, h, w);
    const Taps2 lx = linear_taps(u, w, 1), ly = linear_taps(v, h, w);
#if WIN8
    const int pat = pat_taps4(cx, w), xb = cx.c0.s0;
#define CUBIC_X(p) (pat ? cubic_T_pat((p), cx, cy, pat) : cubic_T((p), cx, cy))
#define LINEAR_LR(p) (pat ? linear_f_pat((p), xb, lx, ly, pat) : linear_f((p), lx, ly))
#else
#define CUBIC_X(p) cubic_T((p), cx, cy)
#define LINEAR_LR(p) linear_f((p), lx, ly)
#endif
    for (int c = 0; c < 3; ++c)
        g.up[c] = CLAMP(CUBIC_X(X + c * hw), 0.0f, 1.0f);
    g.depth = LINEAR_LR(lr + L_DEPTH * hw);
    g.mvx = LINEAR_LR(lr + L_MX * hw) * sx;
    g.mvy = LINEAR_LR(lr + L_MY * hw) * sy;
    g.dd = LINEAR_LR(lr + L_DD * hw);
    g.ddt = LINEAR_LR(lr + L_DDT * hw);
    g.react = LINEAR_LR(lr + L_REACTIVE * hw);
    for (int c = 0; c < 3; ++c) {
        g.bmin[c] = LINEAR_LR(lr + (L_NMIN + c) * hw);
        g.bmax[c] = LINEAR_LR(lr + (L_NMAX + c) * hw);
    }
#undef CUBIC_X
#undef LINEAR_LR
#if NET
    /* s4b: the measurements of the render pixel that holds the output pixel's centre,
     * ((2 I + 1) h) / (2 H) in integers (no jitter, no interpolation: bilinear halved the
     * response to a one-pixel strip) */
    {
        const int ri = ((2 * I + 1) * h) / (2 * H);
        const iv rj = ((2 * J + 1) * w) / (2 * W);
        for (int k = 0; k < MEASURES; ++k)
            g.meas[k] = GATHER(LDF, lr + (L_MEASURE + k) * hw + ri * w, rj);
    }
#endif

    /* s6: the history at P + motion; off-screen or reset pixels start afresh */
    const fv su = CONVERT_FV(J) + g.mvx, sv = (float)I + g.mvy;
    const iv off = (su < -0.5f) | (su > (float)W - 0.5f) | (sv < -0.5f) | (sv > (float)H - 0.5f);
    g.valid = reset ? (iv)(0) : (off == (iv)(0));
    for (int c = 0; c < 3; ++c)
        g.col[c] = g.mn[c] = g.mx[c] = g.up[c];
    g.cnt = FV(0.0f);
    for (int c = 0; c < 6; ++c)
        g.lg[c] = FV(0.0f);
    if (ANY(g.valid)) {
        /* every lane reads at clamped, in-bounds positions; invalid ones are dropped */
        const fv uc = grid_round_trip(CLAMP(su, 0.0f, (float)(W - 1)), W);
        const fv vc = grid_round_trip(CLAMP(sv, 0.0f, (float)(H - 1)), H);
        const Taps4 hx = cubic_taps(uc, W, 1), hy = cubic_taps(vc, H, W);
        const Taps2 gx = linear_taps(uc, W, 1), gy = linear_taps(vc, H, W);
#if WIN8
        const int run4 = run_taps4(hx, hy), run2 = run_taps2(gx, gy);
#define CUBIC_H(p) (run4 ? cubic_T_run((p), hx, hy) : cubic_T((p), hx, hy))
#define LINEAR_H(p) (run2 ? linear_T_run((p), gx, gy) : linear_T((p), gx, gy))
#else
#define CUBIC_H(p) cubic_T((p), hx, hy)
#define LINEAR_H(p) linear_T((p), gx, gy)
#endif
        for (int c = 0; c < 3; ++c)
            g.col[c] = SELECT(g.col[c], CLAMP(CUBIC_H(hist + c * HW), 0.0f, 1.0f), g.valid);
        g.cnt = SELECT(g.cnt, LINEAR_H(hist + 3 * HW), g.valid);
        for (int c = 0; c < 3; ++c) {
            g.mn[c] = SELECT(g.mn[c], LINEAR_H(hist + (4 + c) * HW), g.valid);
            g.mx[c] = SELECT(g.mx[c], LINEAR_H(hist + (7 + c) * HW), g.valid);
        }
        for (int c = 0; c < 6; ++c)
            g.lg[c] = SELECT(g.lg[c], LINEAR_H(hist + (10 + c) * HW), g.valid);
#undef CUBIC_H
#undef LINEAR_H
    }
    return g;
}

/* s9 history clip: up + t (hist - up), t the largest fraction in [0, 1] that keeps all
 * three channels inside the clamp box widened by CLIP_EPS when up is inside it; one t
 * for the three keeps the history's hue, which a per-channel clamp shifts differently
 * each frame as the jittered box moves (flicker). The widening keeps t continuous and
 * bounds how much a channel with a tiny difference d amplifies rounding (by 1/eps). */
inline void clip_history(const Gathered *g, fv hc[3])
{
    fv t = FV(1.0f);
    for (int c = 0; c < 3; ++c) {
        const fv d = g->col[c] - g->up[c];
        const fv lim = SELECT((g->bmin[c] - CLIP_EPS) - g->up[c],
                              (g->bmax[c] + CLIP_EPS) - g->up[c], d > 0.0f);
        const iv nz = d != 0.0f;
        const fv tc = SELECT(FV(1.0f), lim / SELECT(FV(1.0f), d, nz), nz);
        t = FMIN(t, FMAX(tc, 0.0f));
    }
    for (int c = 0; c < 3; ++c)
        hc[c] = g->up[c] + t * (g->col[c] - g->up[c]);
}

inline void keep_history(__global const T *hist, __global T *hist_out, int q, int HW)
{
    __global const TB *src = (__global const TB *)hist;
    __global TB *dst = (__global TB *)hist_out;
    for (int c = 0; c < HIST; ++c)
        dst[c * HW + q] = src[c * HW + q];
}

/* A refused frame (flags from `prepare`) leaves the state as it was: the history
 * is copied through unchanged for this work-item's n pixels at q. */
#define KEEP_HISTORY_IF_REFUSED                                                \
    if (flags[0] & F_REFUSE) {                                                 \
        for (int l = 0; l < n; ++l)                                            \
            keep_history(hist, hist_out, q + l, HW);                           \
        return;                                                                \
    }

#if !NET
/* Rule mode: stages 4-9 in one pass (reference.md s8, s9 "rule"), VEC pixels of a row
 * per work-item. */
/** @param[in]  X       [3, h, w] T the encoded colour
 *  @param[in]  lr      [L_CHANNELS, h, w] float the render-res stack
 *  @param[in]  bx      [W] float render x of each output column's centre, (X + 0.5) * w / W - 0.5
 *  @param[in]  by      [H] float likewise for the rows
 *  @param[in]  jx, jy  the frame's jitter, render pixels
 *  @param[in]  w, h    render width and height
 *  @param[in]  W, H    output width and height
 *  @param[in]  sx, sy  W / w and H / h (motion to output pixels)
 *  @param[in]  reset   1 on a camera cut (the history is not used)
 *  @param[in]  hist    [16, H, W] T the history
 *  @param[out] hist_out [16, H, W] T the next history
 *  @param[out] out      H x W x 3 float, linear, image layout
 *  @param[in]  flags    prepare's flags (a refused frame copies the history through)
 *  @param[in]  depth_threshold  relative depth jump that rejects history (contract.DEPTH_THRESHOLD)
 *  @param[in]  cap      sample counter cap
 *  @param[in]  inv_pq_scale 10000 / nits
 *  @param[in]  exposure the output is multiplied back by it
 *  @param[in]  debug    1: write the debug planes to dbg
 *  @param[out] dbg      [3, H, W] float blend weight, ghost, depth difference (debug = 1)
 *  @note -DNET=0 (this variant); -DHDR=0|1; -DCLIP_EPS=x (contract.RULE_CLIP_EPS); -DVEC=8|4|1
 *  @note -DCLSS_FP16=1: half storage of X, the history, cls_in, aux and logits (T); -DCLSS_CLANG_VECTORS=0|1: builtin-free half loads
 */
__kernel void resolve(__global const T *X, __global const float *lr, __global const float *bx,
                      __global const float *by, float jx, float jy, int w, int h, int W, int H,
                      float sx, float sy, int reset, __global const T *hist,
                      __global T *hist_out, __global float *out, __global const uint *flags,
                      float depth_threshold, float cap, float inv_pq_scale, float exposure,
                      int debug, __global float *dbg)
{
    const int J0 = get_global_id(0) * VEC, I = get_global_id(1);
    if (J0 >= W || I >= H) return;
    const int HW = W * H, q = I * W + J0, n = IMIN(VEC, W - J0);
    KEEP_HISTORY_IF_REFUSED
    const Gathered g = gather(I, IMIN(J0 + LANES, (iv)(W - 1)), X, lr, bx, by, jx, jy, w, h, W, H,
                              sx, sy, reset, hist);
    const iv ghost = (g.ddt > depth_threshold) | (g.valid == (iv)(0));
    const fv cnt = SELECT(FMIN(g.cnt + 1.0f, cap), FV(0.0f), ghost);
    const fv wgt = FMAX(1.0f / (1.0f + cnt), g.react);
    fv hc[3];
    clip_history(&g, hc);
    fv o[3];
    for (int c = 0; c < 3; ++c) {
        const fv u = g.up[c];
        o[c] = wgt * u + (1.0f - wgt) * hc[c];
        st_plane(hist_out, c * HW + q, o[c], n);
        st_plane(hist_out, (4 + c) * HW + q, SELECT(FMIN(g.mn[c], u), u, ghost), n);
        st_plane(hist_out, (7 + c) * HW + q, SELECT(FMAX(g.mx[c], u), u, ghost), n);
    }
    st_plane(hist_out, 3 * HW + q, cnt, n);
    /* rule mode carries no logits: zero bits (0.0 in half and in float). Stored as bits,
     * not through st_plane: with VEC=8 and half storage, six more vstore_half8_rte made
     * PoCL 3.x's compiler (LLVM, AVX-512 host) crash while building this kernel. */
    for (int c = 0; c < 6; ++c)
        for (int l = 0; l < n; ++l)
            ((__global TB *)hist_out)[(10 + c) * HW + q + l] = (TB)0;
    st_rgb(out, q, decode(o[0], inv_pq_scale) * exposure, decode(o[1], inv_pq_scale) * exposure,
           decode(o[2], inv_pq_scale) * exposure, n);
    if (debug) {
        st_plane_f(dbg, q, wgt, n);
        st_plane_f(dbg, HW + q, SELECT(FV(0.0f), FV(1.0f), ghost), n);
        st_plane_f(dbg, 2 * HW + q, g.dd, n);
    }
}

#else
/* Net mode, stages 4-6: the classifier input at the padded size (W16, H16), VEC pixels
 * per work-item (W16 is a multiple of 16, so rows hold whole vectors); pixels past
 * (W, H) replicate the edge (ONNX Pad "edge"). aux [7, H16, W16] T: warped counter,
 * valid, reactive, the clipped history colour (3) and the depth test's difference for
 * `compose`. */
/** @param[in]  X       [3, h, w] T the encoded colour
 *  @param[in]  lr      [L_CHANNELS, h, w] float the render-res stack
 *  @param[in]  bx      [W] float render x of each output column's centre, (X + 0.5) * w / W - 0.5
 *  @param[in]  by      [H] float likewise for the rows
 *  @param[in]  jx, jy  the frame's jitter, render pixels
 *  @param[in]  w, h    render width and height
 *  @param[in]  W, H    output width and height
 *  @param[in]  sx, sy  W / w and H / h (motion to output pixels)
 *  @param[in]  reset   1 on a camera cut (the history is not used)
 *  @param[in]  hist    [16, H, W] T the history
 *  @param[out] cls_in   [CLS_IN, H16, W16] T the classifier input, edge-replicated past (W, H)
 *  @param[out] aux      [7, H16, W16] T warped counter, valid, reactive, clipped history colour 3, the depth test's difference (for compose)
 *  @param[in]  flags    prepare's flags
 *  @param[in]  W16, H16 W and H rounded up to multiples of 16
 *  @note -DNET=1 (this variant); -DHDR=0|1; -DVEC=8|4|1; -DCLIP_EPS=x
 *  @note -DCLSS_FP16=1: half storage of X, the history, cls_in, aux and logits (T); -DCLSS_CLANG_VECTORS=0|1: builtin-free half loads
 */
__kernel void resolve(__global const T *X, __global const float *lr, __global const float *bx,
                      __global const float *by, float jx, float jy, int w, int h, int W, int H,
                      float sx, float sy, int reset, __global const T *hist,
                      __global T *cls_in, __global T *aux, __global const uint *flags,
                      int W16, int H16)
{
    const int J0 = get_global_id(0) * VEC, I16 = get_global_id(1);
    if (J0 >= W16 || I16 >= H16) return;
    /* a refused frame only reaches compose's flag check; its inputs are never used */
    if (flags[0] & F_REFUSE) return;
    const Gathered g = gather(IMIN(I16, H - 1), IMIN(J0 + LANES, (iv)(W - 1)), X, lr, bx, by, jx, jy,
                              w, h, W, H, sx, sy, reset, hist);
    const int P = W16 * H16, r = I16 * W16 + J0;
    /* CLASSIFIER_INPUTS order (weights_tools.networks) */
    for (int c = 0; c < 3; ++c) {
        STV(cls_in, c * P + r, g.up[c]);
        STV(cls_in, (3 + c) * P + r, g.col[c]);
        STV(cls_in, (10 + c) * P + r, g.mn[c]);
        STV(cls_in, (13 + c) * P + r, g.mx[c]);
    }
    STV(cls_in, 6 * P + r, g.depth);
    STV(cls_in, 7 * P + r, g.mvx);
    STV(cls_in, 8 * P + r, g.mvy);
    STV(cls_in, 9 * P + r, 1.0f / (1.0f + g.cnt));
    STV(cls_in, 16 * P + r, g.dd);
    for (int c = 0; c < 6; ++c)
        STV(cls_in, (17 + c) * P + r, g.lg[c]);
    for (int k = 0; k < MEASURES; ++k)
        STV(cls_in, (23 + k) * P + r, g.meas[k]);
    STV(aux, r, g.cnt);
    STV(aux, P + r, SELECT(FV(0.0f), FV(1.0f), g.valid));
    STV(aux, 2 * P + r, g.react);
    fv hc[3];
    clip_history(&g, hc);
    for (int c = 0; c < 3; ++c)
        STV(aux, (3 + c) * P + r, hc[c]);
    STV(aux, 6 * P + r, g.ddt);
}

/* Net mode, stages 6 (logits x2), 7, 8, 9 in one pass, VEC pixels per work-item.
 * logits: [6, H16/2, W16/2] T from the classifier; bilinear x2 (Resize linear,
 * half_pixel) evaluated at the output pixels only, which crops by construction.
 * w1: [HIDDEN, COMP_IN], b1: [HIDDEN], w2: [HIDDEN], b2: [1] (the composition MLP). */
/** @param[in]  cls_in   [CLS_IN, H16, W16] T resolve's classifier input (the composition reads up, depth, motion and the colour range from it)
 *  @param[in]  aux      [7, H16, W16] T resolve's warped counter, valid, reactive, clipped history colour (3), the depth test's difference
 *  @param[in]  logits   [6, H16/2, W16/2] T the classifier's output
 *  @param[in]  W, H     output width and height
 *  @param[in]  W16, H16 the padded size
 *  @param[in]  w1, b1   [HIDDEN, COMP_IN], [HIDDEN] the composition MLP's first layer
 *  @param[in]  w2, b2   [HIDDEN], [1] its second layer
 *  @param[in]  hist     [16, H, W] T the history
 *  @param[out] hist_out [16, H, W] T the next history
 *  @param[out] out      H x W x 3 float, linear, image layout
 *  @param[in]  flags    prepare's flags (a refused frame copies the history through)
 *  @param[in]  depth_threshold relative depth jump that rejects history whatever the
 *                       classifier says (contract.DEPTH_THRESHOLD; > 1 turns the floor off)
 *  @param[in]  vis_margin  the visibility logit's lead over the larger of the other two
 *                       that rejects history (contract.VIS_MARGIN; 0: the paper's argmax;
 *                       unread with -DRULES_BASE=1, where the rules' depth test decides)
 *  @param[in]  cap      sample counter cap
 *  @param[in]  inv_pq_scale 10000 / nits
 *  @param[in]  exposure the output is multiplied back by it
 *  @param[in]  debug    1: write the debug planes to dbg
 *  @param[out] dbg      [3, H, W] float blend weight, ghost, depth difference (debug = 1)
 *  @note -DNET=1 only; -DHIDDEN=n: the MLP's hidden width; -DHDR=0|1; -DVEC=8|4|1
 *  @note -DRULES_BASE=0|1: the paper's blend or the rules' base (config "base", reference.md s9)
 *  @note -DCLSS_FP16=1: half storage of X, the history, cls_in, aux and logits (T); -DCLSS_CLANG_VECTORS=0|1: builtin-free half loads
 */
__kernel void compose(__global const T *cls_in, __global const T *aux,
                      __global const T *logits, int W, int H, int W16, int H16,
                      __constant float *w1, __constant float *b1, __constant float *w2,
                      __constant float *b2, __global const T *hist, __global T *hist_out,
                      __global float *out, __global const uint *flags, float depth_threshold,
                      float vis_margin, float cap, float inv_pq_scale, float exposure, int debug,
                      __global float *dbg)
{
    const int J0 = get_global_id(0) * VEC, I = get_global_id(1);
    if (J0 >= W || I >= H) return;
    const int HW = W * H, q = I * W + J0, n = IMIN(VEC, W - J0);
    KEEP_HISTORY_IF_REFUSED
    /* rows are padded to W16, a multiple of 16 and of VEC: whole vectors stay in bounds */
    const int P = W16 * H16, r = I * W16 + J0;
    const int w2_ = W16 / 2, h2_ = H16 / 2, P2 = w2_ * h2_;

    /* Resize linear half_pixel x2: source x = (J + 0.5) / 2 - 0.5, clamped */
    const fv lxs = CLAMP((CONVERT_FV(J0 + LANES) + 0.5f) / 2.0f - 0.5f, 0.0f, (float)(w2_ - 1));
    const fv lys = FV(CLAMP(((float)I + 0.5f) / 2.0f - 0.5f, 0.0f, (float)(h2_ - 1)));
    const Taps2 lx = linear_taps(lxs, w2_, 1), ly = linear_taps(lys, h2_, w2_);
    fv lg[6];
#if WIN8
    const int lpat = pat_taps2(lx, w2_);
    for (int c = 0; c < 6; ++c)
        lg[c] = lpat ? linear_T_pat(logits + c * P2, lx, ly, lpat) : linear_T(logits + c * P2, lx, ly);
#else
    for (int c = 0; c < 6; ++c)
        lg[c] = linear_T(logits + c * P2, lx, ly);
#endif

    /* visibility ghosting = the visibility logit leads the larger of logits 1-2 by at
     * least vis_margin (lead in this order, as the oracle and the torch twin; margin 0
     * is the argmax, first index on ties), or the rule's depth test (on aux plane 6, the
     * test's difference, s4): the floor under the classifier (reference.md s7) */
#if RULES_BASE
    /* the rules' base (reference.md s9): clss-rules' decision, the depth test alone */
    const iv ghost = (LDV(aux, 6 * P + r) > depth_threshold) | (LDV(aux, P + r) < 0.5f);
#else
    const fv lead = lg[0] - FMAX(lg[1], lg[2]);
    const iv ghost = (lead >= vis_margin) | (LDV(aux, 6 * P + r) > depth_threshold)
                     | (LDV(aux, P + r) < 0.5f);
#endif
    const fv cnt = SELECT(FMIN(LDV(aux, r) + 1.0f, cap), FV(0.0f), ghost);

    /* the composition MLP on COMPOSITION_INPUTS, in their order */
    fv x[COMP_IN];
    for (int c = 0; c < 3; ++c) {
        const fv u = LDV(cls_in, c * P + r);
        x[c] = u;
        x[3 + c] = LDV(aux, (3 + c) * P + r);       /* the clipped history */
        x[10 + c] = SELECT(FMIN(LDV(cls_in, (10 + c) * P + r), u), u, ghost);
        x[13 + c] = SELECT(FMAX(LDV(cls_in, (13 + c) * P + r), u), u, ghost);
    }
    x[6] = LDV(cls_in, 6 * P + r);
    x[7] = LDV(cls_in, 7 * P + r);
    x[8] = LDV(cls_in, 8 * P + r);
    x[9] = 1.0f / (1.0f + cnt);
    for (int c = 0; c < 6; ++c)
        x[16 + c] = lg[c];
    /* a*b + c, contracted to an FMA, and ReLU as a select: mad() and fmax() are
     * out-of-line calls on PoCL 3.0 (common.h), 700 of them per work-item here.
     * MLP_KB hidden units per pass over the inputs, so each x[c] load feeds MLP_KB
     * FMAs; each unit still sums its inputs in order, and z its units in order. */
    fv z = FV(b2[0]);
    for (int k = 0; k < HIDDEN; k += MLP_KB) {
        fv a[MLP_KB];
#pragma unroll
        for (int u = 0; u < MLP_KB; ++u)
            a[u] = FV(b1[k + u]);
#pragma unroll
        for (int c = 0; c < COMP_IN; ++c) {
            const fv xc = x[c];
#pragma unroll
            for (int u = 0; u < MLP_KB; ++u)
                a[u] = FV(w1[(k + u) * COMP_IN + c]) * xc + a[u];
        }
#pragma unroll
        for (int u = 0; u < MLP_KB; ++u)
            z = FV(w2[k + u]) * SELECT(FV(0.0f), a[u], a[u] > 0.0f) + z;
    }
    /* a ghost (visibility ghosting, off screen, reset) drops its history: w = 1. The
     * rules' base: the rules' 1/(1+n) corrected in the logit domain, 1/(1 + n exp(-z)),
     * which is the rules' weight where z = 0 (n >= 1 off the ghosts) */
#if RULES_BASE
    const fv w0 = 1.0f / (1.0f + cnt * EXPV(-z));
#else
    const fv w0 = 1.0f / (1.0f + EXPV(-z));
#endif
    const fv wgt = FMAX(SELECT(w0, FV(1.0f), ghost), LDV(aux, 2 * P + r));

    fv o[3];
    for (int c = 0; c < 3; ++c) {
        o[c] = wgt * x[c] + (1.0f - wgt) * x[3 + c];
        st_plane(hist_out, c * HW + q, o[c], n);
        st_plane(hist_out, (4 + c) * HW + q, x[10 + c], n);
        st_plane(hist_out, (7 + c) * HW + q, x[13 + c], n);
    }
    st_plane(hist_out, 3 * HW + q, cnt, n);
    for (int c = 0; c < 6; ++c)
        st_plane(hist_out, (10 + c) * HW + q, lg[c], n);
    st_rgb(out, q, decode(o[0], inv_pq_scale) * exposure, decode(o[1], inv_pq_scale) * exposure,
           decode(o[2], inv_pq_scale) * exposure, n);
    if (debug) {
        st_plane_f(dbg, q, wgt, n);
        st_plane_f(dbg, HW + q, SELECT(FV(0.0f), FV(1.0f), ghost), n);
        st_plane_f(dbg, 2 * HW + q, LDV(cls_in, 16 * P + r), n);
    }
}
#endif
