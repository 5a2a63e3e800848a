/* Elementwise arithmetic, data movement and the small per-row reductions
 * (softmax, argmax).
 *
 * Build options:
 *   -DOP=n        binary operator (OP_* below) for binary_flat / binary_bcast
 *   -DA_SCALAR=1, -DB_SCALAR=1  binary_flat with that operand a single element
 *   -DUOP=n       unary operator (UOP_* below) for unary
 *   -DPAD_MODE=n  pad: 0 constant, 1 edge, 2 reflect, 3 wrap
 *   -DLAST=1      argmax: the last index of a tied maximum (select_last_index)
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

/* Comparisons store bool as uchar 0/1: a scalar comparison yields 1, a vector
 * one -1 per true component. */
#if OP >= OP_GREATER
typedef uchar O;
#define STO(p, i, v) ((p)[(i)] = (uchar)(v))
#define STO8(p, i, v) vstore8(convert_uchar8(-(v)), 0, (p) + (i))
#else
typedef T O;
#define STO(p, i, v) ST(p, i, v)
#define STO8(p, i, v) ST8(p, i, v)
#endif

/* Same-shape operands (or one of them a single element): eight elements per
 * work-item through vector loads, then a scalar tail. NDRange ceil(n / 8). */
__kernel void binary_flat(__global const T *a, __global const T *b, __global O *out, int n)
{
    const int i = get_global_id(0) * 8;
    if (i >= n) return;
    if (i + 8 <= n) {
#if A_SCALAR
        const A8 x = (A8)(LD(a, 0));
#else
        const A8 x = LD8(a, i);
#endif
#if B_SCALAR
        const A8 y = (A8)(LD(b, 0));
#else
        const A8 y = LD8(b, i);
#endif
        STO8(out, i, BINOP(x, y));
        return;
    }
    for (int j = i; j < n; ++j) {
        const A x = LD(a, A_SCALAR ? 0 : j), y = LD(b, B_SCALAR ? 0 : j);
        STO(out, j, BINOP(x, y));
    }
}

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
    STO(out, ((long)z * D2 + i2) * D3 + i3, BINOP(x, y));
}

/* where(cond, a, b): selects raw bits, so it is bit-exact. */
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

#ifndef UOP
#define UOP UOP_RELU
#endif

/* p0, p1: alpha/beta, or clip's min/max. Relu, clip and hard_sigmoid select,
 * so NaN passes through (as in onnxruntime; fmin/fmax would drop it); a min
 * above max clips everything to max (ONNX). */
#if UOP == UOP_RELU
#define UNOP(x) (((x) < (A)0) ? (A)0 : (x))
#elif UOP == UOP_LEAKY_RELU
#define UNOP(x) (((x) < (A)0) ? (x) * (A)p0 : (x))
#elif UOP == UOP_SIGMOID
#define UNOP(x) ((A)1 / ((A)1 + exp(-(x))))
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
#endif

/* NDRange ceil(n / 8): eight elements per work-item, then a scalar tail. */
__kernel void unary(__global const T *in, __global T *out, int n, float p0, float p1)
{
    const int i = get_global_id(0) * 8;
    if (i >= n) return;
    if (i + 8 <= n) {
        const A8 x = LD8(in, i);
        ST8(out, i, UNOP(x));
        return;
    }
    for (int j = i; j < n; ++j) {
        const A x = LD(in, j);
        ST(out, j, UNOP(x));
    }
}

/* --- data movement ------------------------------------------------------------ */

/* rows x len block copy between row-strided views: concat, split, identity.
 * NDRange (ceil(len / 8), rows). */
__kernel void copy_rows(__global const TB *src, __global TB *dst, int len, int rows,
                        int src_stride, int src_off, int dst_stride, int dst_off)
{
    const int i = get_global_id(0) * 8, r = get_global_id(1);
    if (i >= len || r >= rows) return;
    __global const TB *s = src + (long)r * src_stride + src_off;
    __global TB *d = dst + (long)r * dst_stride + dst_off;
    if (i + 8 <= len) {
        vstore8(vload8(0, s + i), 0, d + i);
        return;
    }
    for (int j = i; j < len; ++j)
        d[j] = s[j];
}

/* out[i0, i1, i2, i3] = src[base + i0*s0 + i1*s1 + i2*s2 + i3*s3]: slice with any
 * steps (negative included). */
__kernel void gather(__global const TB *src, __global TB *dst, int D1, int D2, int D3, int D01,
                     long base, int s0, int s1, int s2, int s3)
{
    const int i3 = get_global_id(0), i2 = get_global_id(1), z = get_global_id(2);
    if (i3 >= D3 || i2 >= D2 || z >= D01) return;
    const int i0 = z / D1, i1 = z % D1;
    dst[((long)z * D2 + i2) * D3 + i3] =
        src[base + (long)i0 * s0 + (long)i1 * s1 + (long)i2 * s2 + (long)i3 * s3];
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

/* --- per-row reductions over a [outer, L, inner] view --------------------------
 * One work-item per (outer, inner) pair, NDRange (inner, outer): neighbouring
 * work-items read neighbouring elements when the axis is not the last one
 * (channel softmax over NCHW). */

/* Numerically stable: exp(x - max) / sum exp(x - max). */
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
    for (int k = 0; k < L; ++k) {
        const long i = base + (long)k * inner;
        ST(out, i, exp(LD(in, i) - m) / s);
    }
}

#ifndef LAST
#define LAST 0
#endif

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
