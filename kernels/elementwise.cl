/* Elementwise arithmetic, data movement and the small per-row reductions
 * (softmax, argmax).
 *
 * Build options:
 *   -DOP=n        binary operator (OP_* below) for binary_flat / binary_bcast
 *   -DA_SCALAR=1, -DB_SCALAR=1  binary_flat with that operand a single element
 *   -DUOP=n       unary operator (UOP_* below) for unary
 *   -DPAD_MODE=n  pad: 0 constant, 1 edge, 2 reflect, 3 wrap
 *   -DCLSS_CLANG_VECTORS=0|1  1: loads and stores through common.h's FLD/FLD8/
 *                 FST/FST8 (binary kernels, unary) and pad8's copies through clang
 *                 vector types, inline, instead of vload8/vload_half/vstore_half
 *                 (out-of-line calls on PoCL); 0 is the reference. The host sets 1
 *                 for binary_bcast8 and pad8 only: measured on PoCL 3.0, fp16
 *                 binary_flat and unary ran 3-4x slower with it.
 *   -DLAST=1      argmax: the last index of a tied maximum (select_last_index)
 *   -DRUN=n       copy_rows: runs of 8 elements per work-item (1 is the reference;
 *                 the host sets 8 on CPU devices, whose per-work-item cost made a
 *                 12-channel 1080p concat move 6 GB/s at one run)
 *
 * Data movement (copy_rows, gather, pad, where) moves raw bits (TB) and is
 * bit-exact; arithmetic loads as A and stores with round-to-nearest-even.
 * Broadcast and strided kernels take shapes coalesced by the host to at most
 * four dimensions [D0, D1, D2, D3] with per-operand element strides (0 along a
 * broadcast dimension); NDRange (D3, D2, D0*D1), so dimension 0 walks the
 * contiguous output.
 */
#include "common.h"


#define OP_ADD 0
#define OP_SUB 1
#define OP_MUL 2
#define OP_DIV 3
#define OP_MIN 4
#define OP_MAX 5
#define OP_PRELU 6
#define OP_GREATER 7
#define OP_LESS 8
#define OP_EQUAL 9
#define OP_GREATER_EQUAL 10
#define OP_LESS_EQUAL 11
#define OP_POW 12
/* comparisons write a uchar mask (OP_GREATER .. OP_LESS_EQUAL) */
#define IS_COMPARISON (OP >= OP_GREATER && OP <= OP_LESS_EQUAL)

#ifndef OP
#define OP OP_ADD
#endif
#ifndef A_SCALAR
#define A_SCALAR 0
#endif
#ifndef B_SCALAR
#define B_SCALAR 0
#endif

/* Each operator is written once for scalars and vectors alike: OpenCL's ?:
 * selects per component when the condition is a vector comparison. Min and
 * max propagate NaN, as onnxruntime does (fmin/fmax would drop it). */
#if OP == OP_ADD
#define BINOP(x, y) ((x) + (y))
#elif OP == OP_SUB
#define BINOP(x, y) ((x) - (y))
#elif OP == OP_MUL
#define BINOP(x, y) ((x) * (y))
#elif OP == OP_DIV
#define BINOP(x, y) ((x) / (y))
#elif OP == OP_MIN
#define BINOP(x, y) ((((x) < (y)) | isnan(x)) ? (x) : (y))
#elif OP == OP_MAX
#define BINOP(x, y) ((((x) > (y)) | isnan(x)) ? (x) : (y))
#elif OP == OP_PRELU
#define BINOP(x, y) (((x) < (A)0) ? (x) * (y) : (x))
#elif OP == OP_POW
#define BINOP(x, y) pow((x), (y))
#elif OP == OP_GREATER
#define BINOP(x, y) ((x) > (y))
#elif OP == OP_LESS
#define BINOP(x, y) ((x) < (y))
#elif OP == OP_EQUAL
#define BINOP(x, y) ((x) == (y))
#elif OP == OP_GREATER_EQUAL
#define BINOP(x, y) ((x) >= (y))
#elif OP == OP_LESS_EQUAL
#define BINOP(x, y) ((x) <= (y))
#endif

/* -DRELU=1: the result goes through Relu before it is stored (clss.Model's
 * binary_relu pass: an arithmetic op whose only consumer is a Relu), one pass over
 * memory instead of two. The same formula as the unary kernel's UOP_RELU. */
#ifndef RELU
#define RELU 0
#endif
#if RELU && IS_COMPARISON
#error "elementwise.cl: -DRELU=1 is for the arithmetic operators"
#endif
#if RELU
#define OUTOP(x, y) RELU_OF(BINOP(x, y))
#define RELU_OF(v) (((v) < (A)0) ? (A)0 : (v))
#else
#define OUTOP(x, y) BINOP(x, y)
#endif

/* Comparisons store bool as uchar 0/1: a scalar comparison yields 1, a vector
 * one -1 per true component. */
#if IS_COMPARISON
typedef uchar O;
#define STO(p, i, v) ((p)[(i)] = (uchar)(v))
#define STO8(p, i, v) vstore8(convert_uchar8(-(v)), 0, (p) + (i))
#else
typedef T O;
#define STO(p, i, v) FST(p, i, v)
#define STO8(p, i, v) FST8(p, i, v)
#endif

/* Same-shape operands (or one of them a single element): eight elements per
 * work-item through vector loads, then a scalar tail. NDRange ceil(n / 8). */
/** @param[in]  a    [n] first operand (one element with -DA_SCALAR=1)
 *  @param[in]  b    [n] second operand (one element with -DB_SCALAR=1)
 *  @param[out] out  [n] a OP b (uchar for comparisons and logic, else T)
 *  @param[in]  n    elements
 *  @note -DOP=n: the operator (OP_* above); -DA_SCALAR, -DB_SCALAR; -DCLSS_CLANG_VECTORS=0|1; -DRELU=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void binary_flat(__global const T *a, __global const T *b, __global O *out, int n)
{
    const int i = get_global_id(0) * 8;
    if (i >= n) return;
    if (i + 8 <= n) {
#if A_SCALAR
        const A8 x = (A8)(FLD(a, 0));
#else
        const A8 x = FLD8(a, i);
#endif
#if B_SCALAR
        const A8 y = (A8)(FLD(b, 0));
#else
        const A8 y = FLD8(b, i);
#endif
        STO8(out, i, OUTOP(x, y));
        return;
    }
    for (int j = i; j < n; ++j) {
        const A x = FLD(a, A_SCALAR ? 0 : j), y = FLD(b, B_SCALAR ? 0 : j);
        STO(out, j, OUTOP(x, y));
    }
}

/** @param[in]  a    first operand
 *  @param[in]  b    second operand
 *  @param[out] out  [D0, D1, D2, D3] a OP b (uchar for comparisons and logic, else T)
 *  @param[in]  D1, D2, D3  the output's coalesced shape [D0, D1, D2, D3] (dimensions 1-3)
 *  @param[in]  D01     D0 * D1, the extent of NDRange dimension 2
 *  @param[in]  a0..a3  a's element strides per output dimension (0 where a broadcasts)
 *  @param[in]  b0..b3  b's element strides
 *  @note -DOP=n: the operator (OP_* above); -DCLSS_CLANG_VECTORS=0|1; -DRELU=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void binary_bcast(__global const T *a, __global const T *b, __global O *out,
                           int D1, int D2, int D3, int D01,
                           int a0, int a1, int a2, int a3, int b0, int b1, int b2, int b3)
{
    const int i3 = get_global_id(0), i2 = get_global_id(1), z = get_global_id(2);
    if (i3 >= D3 || i2 >= D2 || z >= D01) return;
    const int i0 = z / D1, i1 = z % D1;
    const long ia = (long)i0 * a0 + (long)i1 * a1 + (long)i2 * a2 + (long)i3 * a3;
    const long ib = (long)i0 * b0 + (long)i1 * b1 + (long)i2 * b2 + (long)i3 * b3;
    const A x = LD(a, ia), y = LD(b, ib);
    STO(out, ((long)z * D2 + i2) * D3 + i3, OUTOP(x, y));
}

/* binary_bcast with 8 outputs along D3 per work-item, for operands whose
 * innermost stride is 0 (broadcast: one load, splat) or 1 (one vector load):
 * the host's fast path (BCAST_VEC=1 in clss/ops/elementwise.py; binary_bcast
 * is its reference). Same arguments; NDRange (ceil(D3 / 8), D2, D0*D1). */
/** @param[in]  a    first operand
 *  @param[in]  b    second operand
 *  @param[out] out  [D0, D1, D2, D3] a OP b (uchar for comparisons and logic, else T)
 *  @param[in]  D1, D2, D3  the output's coalesced shape [D0, D1, D2, D3] (dimensions 1-3)
 *  @param[in]  D01     D0 * D1, the extent of NDRange dimension 2
 *  @param[in]  a0..a3  a's element strides per output dimension (0 where a broadcasts)
 *  @param[in]  b0..b3  b's element strides
 *  @note -DOP=n: the operator (OP_* above); -DCLSS_CLANG_VECTORS=0|1; -DRELU=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void binary_bcast8(__global const T *a, __global const T *b, __global O *out,
                            int D1, int D2, int D3, int D01,
                            int a0, int a1, int a2, int a3, int b0, int b1, int b2, int b3)
{
    const int i3 = get_global_id(0) * 8, i2 = get_global_id(1), z = get_global_id(2);
    if (i3 >= D3 || i2 >= D2 || z >= D01) return;
    const int i0 = z / D1, i1 = z % D1;
    const long ia = (long)i0 * a0 + (long)i1 * a1 + (long)i2 * a2 + (long)i3 * a3;
    const long ib = (long)i0 * b0 + (long)i1 * b1 + (long)i2 * b2 + (long)i3 * b3;
    const long o = ((long)z * D2 + i2) * D3 + i3;
    if (i3 + 8 <= D3) {
        A8 x, y;
        if (a3)
            x = FLD8(a, ia);
        else
            x = (A8)(FLD(a, ia));
        if (b3)
            y = FLD8(b, ib);
        else
            y = (A8)(FLD(b, ib));
        STO8(out, o, OUTOP(x, y));
        return;
    }
    for (int e = 0; i3 + e < D3; ++e) {
        const A x = FLD(a, ia + (long)e * a3), y = FLD(b, ib + (long)e * b3);
        STO(out, o + e, OUTOP(x, y));
    }
}

/* where(cond, a, b): selects raw bits, so it is bit-exact. */
/** @param[in]  c    the condition (uchar, nonzero = true)
 *  @param[in]  a    taken where c is true (raw bits)
 *  @param[in]  b    taken where c is false
 *  @param[out] out  [D0, D1, D2, D3] output
 *  @param[in]  D1, D2, D3  the output's coalesced shape [D0, D1, D2, D3] (dimensions 1-3)
 *  @param[in]  D01     D0 * D1, the extent of NDRange dimension 2
 *  @param[in]  c0..c3  c's element strides per output dimension (0 where it broadcasts)
 *  @param[in]  a0..a3  a's element strides
 *  @param[in]  b0..b3  b's element strides
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void where_bcast(__global const uchar *c, __global const TB *a, __global const TB *b,
                          __global TB *out, int D1, int D2, int D3, int D01,
                          int c0, int c1, int c2, int c3, int a0, int a1, int a2, int a3,
                          int b0, int b1, int b2, int b3)
{
    const int i3 = get_global_id(0), i2 = get_global_id(1), z = get_global_id(2);
    if (i3 >= D3 || i2 >= D2 || z >= D01) return;
    const int i0 = z / D1, i1 = z % D1;
    const long ic = (long)i0 * c0 + (long)i1 * c1 + (long)i2 * c2 + (long)i3 * c3;
    const long ia = (long)i0 * a0 + (long)i1 * a1 + (long)i2 * a2 + (long)i3 * a3;
    const long ib = (long)i0 * b0 + (long)i1 * b1 + (long)i2 * b2 + (long)i3 * b3;
    out[((long)z * D2 + i2) * D3 + i3] = c[ic] ? a[ia] : b[ib];
}

/* --- unary ------------------------------------------------------------------ */
#define UOP_RELU 0
#define UOP_LEAKY_RELU 1
#define UOP_SIGMOID 2
#define UOP_TANH 3
#define UOP_ELU 4
#define UOP_HARD_SIGMOID 5
#define UOP_ABS 6
#define UOP_NEG 7
#define UOP_EXP 8
#define UOP_SQRT 9
#define UOP_CLIP 10
#define UOP_HARD_SWISH 11
#define UOP_GELU 12
#define UOP_GELU_TANH 13
#define UOP_ERF 14
#define UOP_LOG 15
#define UOP_RECIPROCAL 16
#define UOP_SOFTPLUS 17
#define UOP_SOFTSIGN 18
#define UOP_SELU 19
#define UOP_CELU 20
#define UOP_THRESHOLDED_RELU 21
#define UOP_MISH 22
#define UOP_FLOOR 23
#define UOP_CEIL 24
#define UOP_ROUND 25
#define UOP_SIGN 26
#define UOP_SIN 27
#define UOP_COS 28

#ifndef UOP
#define UOP UOP_RELU
#endif

/* erf as Abramowitz and Stegun 7.1.26 above |x| = 0.5 (absolute error <= 1.5e-7, below
 * float32's resolution of erf's range there): one exp and a division where PoCL's erf is a library call of
 * about six times the cost (Gelu at 540x960: 39 ms against 6 for a sigmoid). Generic in the
 * vector width; -DCLSS_LIBRARY_ERF=1 takes the builtin instead. */
#ifndef CLSS_LIBRARY_ERF
#define CLSS_LIBRARY_ERF 0
#endif
#if CLSS_LIBRARY_ERF
#define ERF(x) erf(x)
#else
#define ERF_T(ax) ((A)1 / ((A)1 + (A)0.3275911f * (ax)))
#define ERF_POLY(t) ((t) * ((A)0.254829592f + (t) * ((A)-0.284496736f + (t) * ((A)1.421413741f \
                     + (t) * ((A)-1.453152027f + (t) * (A)1.061405429f)))))
#define ERF_POS(ax) ((A)1 - ERF_POLY(ERF_T(ax)) * exp(-(ax) * (ax)))
/* below |x| = 0.5 its Taylor series (to x^11, error < 1e-9), where 1 - poly * exp would
 * cancel and leave only an absolute error: erf(x) of small x keeps its relative precision */
#define ERF_X2(x) ((x) * (x))
#define ERF_SMALL(x) ((A)1.1283791671f * (x) * ((A)1 + ERF_X2(x) * ((A)-0.3333333333f + ERF_X2(x) * \
                      ((A)0.1f + ERF_X2(x) * ((A)-0.0238095238f + ERF_X2(x) * ((A)0.0046296296f \
                      + ERF_X2(x) * (A)-0.0007575758f))))))
#define ERF_LARGE(x) (((x) < (A)0) ? -ERF_POS(-(x)) : ERF_POS(x))
#define ERF(x) ((fabs(x) < (A)0.5f) ? ERF_SMALL(x) : ERF_LARGE(x))
#endif

/* p0, p1: alpha/beta, or clip's min/max. Relu, clip and hard_sigmoid select,
 * so NaN passes through (as in onnxruntime; fmin/fmax would drop it); a min
 * above max clips everything to max (ONNX). */
#if UOP == UOP_RELU
#define UNOP(x) (((x) < (A)0) ? (A)0 : (x))
#elif UOP == UOP_LEAKY_RELU
#define UNOP(x) (((x) < (A)0) ? (x) * (A)p0 : (x))
#elif UOP == UOP_SIGMOID
#define UNOP(x) SIGMOID(x)
#elif UOP == UOP_TANH
#define UNOP(x) tanh(x)
#elif UOP == UOP_ELU
#define UNOP(x) (((x) < (A)0) ? (A)p0 * expm1(x) : (x))
#elif UOP == UOP_HARD_SIGMOID
#define HS_LINEAR(x) ((A)p0 * (x) + (A)p1)
#define HS_LO(x) ((HS_LINEAR(x) < (A)0) ? (A)0 : HS_LINEAR(x))
#define UNOP(x) ((HS_LO(x) > (A)1) ? (A)1 : HS_LO(x))
#elif UOP == UOP_ABS
#define UNOP(x) fabs(x)
#elif UOP == UOP_NEG
#define UNOP(x) (-(x))
#elif UOP == UOP_EXP
#define UNOP(x) exp(x)
#elif UOP == UOP_SQRT
#define UNOP(x) sqrt(x)
#elif UOP == UOP_CLIP
#define CLIP_LO(x) (((x) < (A)p0) ? (A)p0 : (x))
#define UNOP(x) ((CLIP_LO(x) > (A)p1) ? (A)p1 : CLIP_LO(x))
#elif UOP == UOP_HARD_SWISH
/* x * HardSigmoid(x) with ONNX's fixed alpha = 1/6, beta = 0.5 */
#define HSW_LIN(x) ((x) * (A)(1.0f / 6.0f) + (A)0.5f)
#define HSW_LO(x) ((HSW_LIN(x) < (A)0) ? (A)0 : HSW_LIN(x))
#define UNOP(x) ((x) * ((HSW_LO(x) > (A)1) ? (A)1 : HSW_LO(x)))
#elif UOP == UOP_GELU
#define UNOP(x) ((A)0.5f * (x) * ((A)1 + ERF((x) * (A)M_SQRT1_2_F)))
#elif UOP == UOP_GELU_TANH
#define UNOP(x) ((A)0.5f * (x) * ((A)1 + tanh((A)0.7978845608028654f * ((x) + (A)0.044715f * (x) * (x) * (x)))))
#elif UOP == UOP_ERF
#define UNOP(x) ERF(x)
#elif UOP == UOP_LOG
#define UNOP(x) log(x)
#elif UOP == UOP_RECIPROCAL
#define UNOP(x) ((A)1 / (x))
#elif UOP == UOP_SOFTPLUS
/* log(1 + exp(x)) without overflow: max(x, 0) + log1p(exp(-|x|)) */
#define SOFTPLUS(x) (fmax((x), (A)0) + log1p(exp(-fabs(x))))
#define UNOP(x) SOFTPLUS(x)
#elif UOP == UOP_SOFTSIGN
#define UNOP(x) ((x) / ((A)1 + fabs(x)))
#elif UOP == UOP_SELU
/* p0: alpha, p1: gamma */
#define UNOP(x) (((x) > (A)0) ? (A)p1 * (x) : (A)p1 * ((A)p0 * exp(x) - (A)p0))
#elif UOP == UOP_CELU
/* p0: alpha */
#define UNOP(x) (fmax((x), (A)0) + fmin((A)0, (A)p0 * (exp((x) / (A)p0) - (A)1)))
#elif UOP == UOP_THRESHOLDED_RELU
#define UNOP(x) (((x) > (A)p0) ? (x) : (A)0)
#elif UOP == UOP_MISH
#define UNOP(x) ((x) * tanh(fmax((x), (A)0) + log1p(exp(-fabs(x)))))
#elif UOP == UOP_FLOOR
#define UNOP(x) floor(x)
#elif UOP == UOP_CEIL
#define UNOP(x) ceil(x)
#elif UOP == UOP_ROUND
/* ties to even, as ONNX Round */
#define UNOP(x) rint(x)
#elif UOP == UOP_SIGN
/* NaN stays NaN (OpenCL's sign gives 0 there) */
#define UNOP(x) (isnan(x) ? (x) : sign(x))
#elif UOP == UOP_SIN
#define UNOP(x) sin(x)
#elif UOP == UOP_COS
#define UNOP(x) cos(x)
#endif

/* NDRange ceil(n / 8): eight elements per work-item, then a scalar tail. */
/** @param[in]  in   [n] input
 *  @param[out] out  [n] UOP(in)
 *  @param[in]  n    elements
 *  @param[in]  p0   the operator's first parameter (clip's low bound, leaky_relu's slope, ...)
 *  @param[in]  p1   the second (clip's high bound)
 *  @note -DUOP=n: the operator (UOP_* above); -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void unary(__global const T *in, __global T *out, int n, float p0, float p1)
{
    const int i = get_global_id(0) * 8;
    if (i >= n) return;
    if (i + 8 <= n) {
        const A8 x = FLD8(in, i);
        FST8(out, i, UNOP(x));
        return;
    }
    for (int j = i; j < n; ++j) {
        const A x = FLD(in, j);
        FST(out, j, UNOP(x));
    }
}

/* Clip with its bounds as tensors (ONNX Clip-11+, min/max given as inputs computed at run
 * time): the bounds are read from one-element buffers, so a new value needs no new launch
 * setup. Same selects as UOP_CLIP: NaN passes through, min above max gives max. */
#ifndef CLIP_LO_BUF
#define CLIP_LO_BUF 0
#endif
#ifndef CLIP_HI_BUF
#define CLIP_HI_BUF 0
#endif
/** @param[in]  in   [n] input
 *  @param[out] out  [n] min(max(in, lo), hi)
 *  @param[in]  n    elements
 *  @param[in]  lo   [1] the low bound (read with -DCLIP_LO_BUF=1, else unbounded)
 *  @param[in]  hi   [1] the high bound (read with -DCLIP_HI_BUF=1, else unbounded)
 *  @note -DCLIP_LO_BUF=0|1, -DCLIP_HI_BUF=0|1: which bounds are given
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void clip_buf(__global const T *in, __global T *out, int n, __global const T *lo,
                       __global const T *hi)
{
    const int i = get_global_id(0) * 8;
    if (i >= n) return;
#if CLIP_LO_BUF
    const A l = LD(lo, 0);
#endif
#if CLIP_HI_BUF
    const A h = LD(hi, 0);
#endif
    if (i + 8 <= n) {
        A8 x = FLD8(in, i);
#if CLIP_LO_BUF
        x = (x < (A8)l) ? (A8)l : x;
#endif
#if CLIP_HI_BUF
        x = (x > (A8)h) ? (A8)h : x;
#endif
        FST8(out, i, x);
        return;
    }
    for (int j = i; j < n; ++j) {
        A x = FLD(in, j);
#if CLIP_LO_BUF
        x = (x < l) ? l : x;
#endif
#if CLIP_HI_BUF
        x = (x > h) ? h : x;
#endif
        FST(out, j, x);
    }
}

/* --- data movement ------------------------------------------------------------ */

/* rows x len block copy between row-strided views: concat, split, identity.
 * NDRange (ceil(len / 8), rows). */
/** @param[in]  src         source (raw bits)
 *  @param[out] dst         destination
 *  @param[in]  len         elements per row
 *  @param[in]  rows        rows
 *  @param[in]  src_stride  elements between source rows
 *  @param[in]  src_off     first source element
 *  @param[in]  dst_stride  elements between destination rows
 *  @param[in]  dst_off     first destination element
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
#ifndef RUN
#define RUN 1
#endif
__kernel void copy_rows(__global const TB *src, __global TB *dst, int len, int rows,
                        int src_stride, int src_off, int dst_stride, int dst_off)
{
    const int i0 = get_global_id(0) * 8 * RUN, r = get_global_id(1);
    if (i0 >= len || r >= rows) return;
    __global const TB *s = src + (long)r * src_stride + src_off;
    __global TB *d = dst + (long)r * dst_stride + dst_off;
    for (int k = 0; k < RUN; ++k) {
        const int i = i0 + 8 * k;
        if (i + 8 <= len) {
            /* TB_LD8/TB_ST8 (common.h): on PoCL not its out-of-line vload8/vstore8
             * calls, which held a 25 MB copy at 18 GB/s of traffic against memcpy's 27 */
            TB_ST8(d + i, TB_LD8(s + i));
        } else {
            for (int j = i; j < len; ++j)
                d[j] = s[j];
            break;
        }
    }
}

/* out[i0, i1, i2, i3] = src[base + i0*s0 + i1*s1 + i2*s2 + i3*s3]: slice with any
 * steps (negative included). */
/** @param[in]  src     source (raw bits)
 *  @param[out] dst     [D0, D1, D2, D3] output
 *  @param[in]  D1, D2, D3  the output's coalesced shape [D0, D1, D2, D3] (dimensions 1-3)
 *  @param[in]  D01     D0 * D1, the extent of NDRange dimension 2
 *  @param[in]  base    source element of output (0, 0, 0, 0)
 *  @param[in]  s0..s3  source element strides per output dimension (negative for reversed steps)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void gather(__global const TB *src, __global TB *dst, int D1, int D2, int D3, int D01,
                     long base, int s0, int s1, int s2, int s3)
{
    const int i3 = get_global_id(0), i2 = get_global_id(1), z = get_global_id(2);
    if (i3 >= D3 || i2 >= D2 || z >= D01) return;
    const int i0 = z / D1, i1 = z % D1;
    dst[((long)z * D2 + i2) * D3 + i3] =
        src[base + (long)i0 * s0 + (long)i1 * s1 + (long)i2 * s2 + (long)i3 * s3];
}

/* gather for strided copies that stay above four dimensions after coalescing (a 5-D or
 * 6-D transpose: attention heads, window partitions): one output element per work-item,
 * its index split over up to eight dimensions. NDRange (n). */
/** @param[in]  src     source (raw bits)
 *  @param[out] dst     [D0, ..., D7] output, contiguous
 *  @param[in]  n       output elements
 *  @param[in]  base    source element of output (0, ..., 0)
 *  @param[in]  D1..D7  the output's shape (D0 is implied by n), 1 for unused leading dims
 *  @param[in]  s0..s7  source element strides per output dimension
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void gather8(__global const TB *src, __global TB *dst, long n, long base,
                      int D1, int D2, int D3, int D4, int D5, int D6, int D7,
                      int s0, int s1, int s2, int s3, int s4, int s5, int s6, int s7)
{
    const long i = get_global_id(0);
    if (i >= n) return;
    long r = i, off = base;
    off += (long)(r % D7) * s7; r /= D7;
    off += (long)(r % D6) * s6; r /= D6;
    off += (long)(r % D5) * s5; r /= D5;
    off += (long)(r % D4) * s4; r /= D4;
    off += (long)(r % D3) * s3; r /= D3;
    off += (long)(r % D2) * s2; r /= D2;
    off += (long)(r % D1) * s1; r /= D1;
    off += r * s0;
    dst[i] = src[off];
}

/* ONNX Gather with indices known at load: out[o, i, j] = src[o, idx[i], j] over a
 * [outer, L, inner] view of the data; NDRange (inner, n_idx, outer). */
/** @param[in]  src    [outer, L, inner] data (raw bits)
 *  @param[in]  idx    [n_idx] indices, already in [0, L)
 *  @param[out] dst    [outer, n_idx, inner]
 *  @param[in]  L      length of the gathered axis
 *  @param[in]  inner  elements after the axis
 *  @param[in]  n_idx  indices
 *  @param[in]  outer  elements before the axis
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void gather_axis(__global const TB *src, __global const int *idx, __global TB *dst,
                          int L, int inner, int n_idx, int outer)
{
    const int j = get_global_id(0), k = get_global_id(1), o = get_global_id(2);
    if (j >= inner || k >= n_idx || o >= outer) return;
    dst[((long)o * n_idx + k) * inner + j] = src[((long)o * L + idx[k]) * inner + j];
}

#ifndef PAD_MODE
#define PAD_MODE 0
#endif

/* Input coordinate of output coordinate o along an axis of length n padded by
 * p in front (negative p crops); -1 marks constant padding. */
inline int pad_src(int o, int p, int n)
{
    const int i = o - p;
#if PAD_MODE == 0
    return (i < 0 || i >= n) ? -1 : i;
#elif PAD_MODE == 1
    return clamp(i, 0, n - 1);
#elif PAD_MODE == 2
    if (n == 1) return 0;
    const int period = 2 * n - 2;
    int m = i % period;
    m = m < 0 ? m + period : m;
    return m < n ? m : period - m;
#else
    const int m = i % n;
    return m < 0 ? m + n : m;
#endif
}

/** @param[in]  src     [N0, N1, N2, N3] input (raw bits)
 *  @param[out] dst     [D0, D1, D2, D3] output
 *  @param[in]  D1, D2, D3  the output's coalesced shape [D0, D1, D2, D3] (dimensions 1-3)
 *  @param[in]  D01     D0 * D1, the extent of NDRange dimension 2
 *  @param[in]  N0..N3  the input's shape
 *  @param[in]  P0..P3  begin pads
 *  @param[in]  value   the constant of PAD_MODE 0, as raw bits
 *  @note -DPAD_MODE=0..3: constant, edge, reflect, wrap
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void pad(__global const TB *src, __global TB *dst, int D1, int D2, int D3, int D01,
                  int N0, int N1, int N2, int N3, int P0, int P1, int P2, int P3, TB value)
{
    const int o3 = get_global_id(0), o2 = get_global_id(1), z = get_global_id(2);
    if (o3 >= D3 || o2 >= D2 || z >= D01) return;
    const int o0 = z / D1, o1 = z % D1;
    const int i0 = pad_src(o0, P0, N0), i1 = pad_src(o1, P1, N1);
    const int i2 = pad_src(o2, P2, N2), i3 = pad_src(o3, P3, N3);
    const long o = ((long)z * D2 + o2) * D3 + o3;
    if ((i0 | i1 | i2 | i3) < 0)
        dst[o] = value;
    else
        dst[o] = src[(((long)i0 * N1 + i1) * N2 + i2) * N3 + i3];
}

/* pad, 8 outputs along the last dimension per work-item (the host's fast path,
 * PAD_VEC=1 in clss/ops/elementwise.py; `pad` above, one output per work-item,
 * is its reference): the outer coordinates are mapped once, a block whose
 * source lies wholly inside the input row is one 8-element copy, a block in a
 * constant-padded row one 8-element fill; others go element by element.
 * -DPAD_BLOCKS=n (default 8): blocks of 8 per work-item, consecutive along the row.
 * Same arguments as `pad`; NDRange (ceil(D3 / (8 * PAD_BLOCKS)), D2, D0*D1). */
/* TB_LD8 / TB_ST8: common.h */
#ifndef PAD_BLOCKS
#define PAD_BLOCKS 8
#endif
/** @param[in]  src     [N0, N1, N2, N3] input (raw bits)
 *  @param[out] dst     [D0, D1, D2, D3] output
 *  @param[in]  D1, D2, D3  the output's coalesced shape [D0, D1, D2, D3] (dimensions 1-3)
 *  @param[in]  D01     D0 * D1, the extent of NDRange dimension 2
 *  @param[in]  N0..N3  the input's shape
 *  @param[in]  P0..P3  begin pads
 *  @param[in]  value   the constant of PAD_MODE 0, as raw bits
 *  @note -DPAD_MODE=0..3: constant, edge, reflect, wrap
 *  @note -DPAD_BLOCKS=n: blocks of 8 outputs per work-item (default 8); -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void pad8(__global const TB *src, __global TB *dst, int D1, int D2, int D3, int D01,
                   int N0, int N1, int N2, int N3, int P0, int P1, int P2, int P3, TB value)
{
    const int b0 = get_global_id(0) * PAD_BLOCKS, o2 = get_global_id(1), z = get_global_id(2);
    if (b0 * 8 >= D3 || o2 >= D2 || z >= D01) return;
    const int o0 = z / D1, o1 = z % D1;
    const int i0 = pad_src(o0, P0, N0), i1 = pad_src(o1, P1, N1), i2 = pad_src(o2, P2, N2);
    const int pad_row = (i0 | i1 | i2) < 0;      /* constant mode: a padded row */
    __global TB *drow = dst + ((long)z * D2 + o2) * D3;
    const __global TB *s = src + (pad_row ? 0 : (((long)i0 * N1 + i1) * N2 + i2) * N3);
    for (int b = 0; b < PAD_BLOCKS; ++b) {
        const int o3 = (b0 + b) * 8;
        if (o3 >= D3)
            break;
        __global TB *d = drow + o3;
        const int n = min(8, D3 - o3);
        const int i3 = o3 - P3;
        if (n == 8 && pad_row) {
            TB_ST8(d, (TB8)value);
        } else if (n == 8 && i3 >= 0 && i3 + 8 <= N3) {
            TB_ST8(d, TB_LD8(s + i3));
        } else {
            for (int e = 0; e < n; ++e) {
                const int j = pad_row ? -1 : pad_src(o3 + e, P3, N3);
                d[e] = j < 0 ? value : s[j];
            }
        }
    }
}

/* --- per-row reductions over a [outer, L, inner] view --------------------------
 * One work-item per (outer, inner) pair, NDRange (inner, outer): neighbouring
 * work-items read neighbouring elements when the axis is not the last one
 * (channel softmax over NCHW). */

#ifndef LOG_SOFTMAX
#define LOG_SOFTMAX 0
#endif

/* Numerically stable: exp(x - max) / sum exp(x - max). */
/** @param[in]  in     [outer, L, inner] input
 *  @param[out] out    the same shape
 *  @param[in]  L      length of the softmax axis
 *  @param[in]  inner  elements after the axis (NDRange dimension 0)
 *  @param[in]  outer  elements before the axis (NDRange dimension 1)
 *  @note -DLOG_SOFTMAX=1: LogSoftmax, x - max - log(sum exp(x - max))
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void softmax(__global const T *in, __global T *out, int L, int inner, int outer)
{
    const int j = get_global_id(0), o = get_global_id(1);
    if (j >= inner || o >= outer) return;
    const long base = (long)o * L * inner + j;
    A m = LD(in, base);
    for (int k = 1; k < L; ++k)
        m = fmax(m, LD(in, base + (long)k * inner));
    A s = A_ZERO;
    for (int k = 0; k < L; ++k)
        s += exp(LD(in, base + (long)k * inner) - m);
#if LOG_SOFTMAX
    const A ls = log(s);   /* (x - max) - log(s): m + log(s) would round away log(s) at large x */
    for (int k = 0; k < L; ++k) {
        const long i = base + (long)k * inner;
        ST(out, i, (LD(in, i) - m) - ls);
    }
#else
    for (int k = 0; k < L; ++k) {
        const long i = base + (long)k * inner;
        ST(out, i, exp(LD(in, i) - m) / s);
    }
#endif
}

/* softmax over the last axis (inner == 1: attention scores, a classifier's logits), one
 * row per work-item, eight lanes at a time: the host's fast path (elementwise.softmax_rows
 * in clss/ops/elementwise.py; `softmax` with inner 1, whose neighbouring work-items walk
 * rows L apart, is its reference). NDRange (outer). */
/** @param[in]  in     [outer, L] input
 *  @param[out] out    the same shape
 *  @param[in]  L      length of the softmax axis (the last)
 *  @param[in]  outer  rows
 *  @note -DLOG_SOFTMAX=1: LogSoftmax; -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void softmax_rows(__global const T *in, __global T *out, int L, int outer)
{
    const int o = get_global_id(0);
    if (o >= outer) return;
    __global const T *x = in + (long)o * L;
    __global T *y = out + (long)o * L;
    int j = 0;
    A8 m8 = (A8)(-INFINITY);
    for (; j + 8 <= L; j += 8)
        m8 = fmax(m8, FLD8(x, j));
    A m = fmax(fmax(fmax(m8.s0, m8.s1), fmax(m8.s2, m8.s3)), fmax(fmax(m8.s4, m8.s5), fmax(m8.s6, m8.s7)));
    for (; j < L; ++j)
        m = fmax(m, FLD(x, j));
    A8 s8 = (A8)(A_ZERO);
#if LOG_SOFTMAX
    for (j = 0; j + 8 <= L; j += 8)
        s8 += exp(FLD8(x, j) - m);
    A s = ((s8.s0 + s8.s1) + (s8.s2 + s8.s3)) + ((s8.s4 + s8.s5) + (s8.s6 + s8.s7));
    for (; j < L; ++j)
        s += exp(FLD(x, j) - m);
#else
    /* exp(x - max) is written as it is summed, then divided in place: one exp per element */
    for (j = 0; j + 8 <= L; j += 8) {
        const A8 e = exp(FLD8(x, j) - m);
        FST8(y, j, e);
        s8 += e;
    }
    A s = ((s8.s0 + s8.s1) + (s8.s2 + s8.s3)) + ((s8.s4 + s8.s5) + (s8.s6 + s8.s7));
    for (; j < L; ++j) {
        const A e = exp(FLD(x, j) - m);
        FST(y, j, e);
        s += e;
    }
#endif
#if LOG_SOFTMAX
    const A ls = log(s);
    for (j = 0; j + 8 <= L; j += 8)
        FST8(y, j, (FLD8(x, j) - m) - ls);
    for (; j < L; ++j)
        FST(y, j, (FLD(x, j) - m) - ls);
#else
    for (j = 0; j + 8 <= L; j += 8)
        FST8(y, j, FLD8(y, j) / s);
    for (; j < L; ++j)
        FST(y, j, FLD(y, j) / s);
#endif
}

#ifndef LAST
#define LAST 0
#endif

/** @param[in]  in     [outer, L, inner] input
 *  @param[out] out    [outer, inner] index of the maximum along the axis (long)
 *  @param[in]  L      length of the axis
 *  @param[in]  inner  elements after the axis (NDRange dimension 0)
 *  @param[in]  outer  elements before the axis (NDRange dimension 1)
 *  @note -DLAST=0|1: the first or the last index of a tied maximum
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void argmax(__global const T *in, __global long *out, int L, int inner, int outer)
{
    const int j = get_global_id(0), o = get_global_id(1);
    if (j >= inner || o >= outer) return;
    const long base = (long)o * L * inner + j;
    A m = LD(in, base);
    int arg = 0;
    for (int k = 1; k < L; ++k) {
        const A v = LD(in, base + (long)k * inner);
#if LAST
        if (v >= m) {
#else
        if (v > m) {
#endif
            m = v;
            arg = k;
        }
    }
    out[(long)o * inner + j] = arg;
}
