/* Scatter with atomic reductions: FSR2-style previous-depth reconstruction and ONNX
 * ScatterElements (opset 18) on float data.
 *
 * Build options:
 *   -DRED=0..4    ScatterElements reduction: none, add, mul, max, min
 *   -DIDX64=0|1   indices are int (0) or long (1, ONNX int64)
 *   -DDEPTH_MAX=0|1  scatter_depth keeps the max (reversed-Z: nearest = largest) or min
 *
 * Atomics are 32-bit (core since OpenCL 1.1), so reductions accumulate in a uint
 * buffer holding float32 bits, also for fp16 data (widened on entry, rounded once at
 * the end). Max and min use atomic_max/atomic_min on an order-preserving key: a float's
 * bits with the sign bit flipped for positives and all bits flipped for negatives
 * order like the floats themselves (-0 just below +0; NaNs beyond the infinities).
 * For depth >= 0 the key is not needed (non-negative float bits already order as uints),
 * so scatter_depth stores plain float bits that a later pass reads back as float.
 * add and mul are compare-and-swap loops; none is atomic_xchg, so duplicate indices
 * are not a data race, but which update lands is unspecified, as in ONNX.
 */
#include "common.h"

#define RED_NONE 0
#define RED_ADD 1
#define RED_MUL 2
#define RED_MAX 3
#define RED_MIN 4

#ifndef RED
#define RED RED_NONE
#endif
#ifndef IDX64
#define IDX64 1
#endif
#ifndef DEPTH_MAX
#define DEPTH_MAX 1
#endif

#if IDX64
typedef long IDX;
#else
typedef int IDX;
#endif

#define KEYED (RED == RED_MAX || RED == RED_MIN)

inline uint float_key(uint b) { return b ^ ((b >> 31) ? 0xFFFFFFFFu : 0x80000000u); }
inline uint key_float(uint k) { return k ^ ((k >> 31) ? 0x80000000u : 0xFFFFFFFFu); }

/** @param[out] buf    [n] buffer to fill
 *  @param[in]  value  the 32-bit value written to every element
 *  @param[in]  n      elements
 */
__kernel void fill_u32(__global uint *buf, uint value, int n)
{
    const int i = get_global_id(0);
    if (i < n) buf[i] = value;
}

/* acc[i] = data[i] as float32 bits (keyed for max/min). acc may alias data in fp32:
 * each work-item reads and writes only its own element. */
/** @param[in]  data  [n] the data tensor
 *  @param[out] acc   [n] float32 bits of data (order-keyed for max/min); may alias data in fp32
 *  @param[in]  n     elements
 *  @note -DRED=0..4: the reduction (keys for max and min)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void scatter_init(__global const T *data, __global uint *acc, int n)
{
    const int i = get_global_id(0);
    if (i >= n) return;
    const uint b = as_uint((float)LD(data, i));
#if KEYED
    acc[i] = float_key(b);
#else
    acc[i] = b;
#endif
}

/* out[i] = acc[i] back in the storage type (the only rounding in fp16). */
/** @param[in]  acc  [n] the accumulator
 *  @param[out] out  [n] acc in the storage type
 *  @param[in]  n    elements
 *  @note -DRED=0..4: the reduction (keys for max and min)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void scatter_final(__global const uint *acc, __global T *out, int n)
{
    const int i = get_global_id(0);
    if (i >= n) return;
#if KEYED
    ST(out, i, as_float(key_float(acc[i])));
#else
    ST(out, i, as_float(acc[i]));
#endif
}

#define DIM(k) { const int j = t % ishape.s##k; t /= ishape.s##k; off += (long)j * dstride.s##k; }

/* One work-item per element of indices/updates (dimension 0 walks them contiguously).
 * ishape: the indices' shape, innermost dimension in s0, padded with 1; dstride: the
 * data's element strides in the same order, 0 at the scatter axis, whose stride is
 * astride. Negative indices count from the end; out-of-range ones are dropped (ONNX
 * calls them an error; a kernel cannot raise, and must not write out of bounds). */
/** @param[in]     indices  indices, the shape ishape (int or long)
 *  @param[in]     updates  updates, the same shape
 *  @param[in,out] acc      the data as float32 bits (scatter_init), updated in place
 *  @param[in]     n        elements of indices
 *  @param[in]     ishape   the indices' shape, innermost dimension in s0, padded with 1
 *  @param[in]     dstride  the data's element strides in that order, 0 at the scatter axis
 *  @param[in]     adim     the data's extent along the scatter axis
 *  @param[in]     astride  the data's stride along the scatter axis
 *  @note -DRED=0..4: none, add, mul, max, min; -DIDX64=0|1: int or long indices
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void scatter_elements(__global const IDX *indices, __global const T *updates,
                               __global uint *acc, int n, int8 ishape, int8 dstride,
                               int adim, int astride)
{
    const int u = get_global_id(0);
    if (u >= n) return;
    long idx = indices[u];
    if (idx < 0) idx += adim;
    if (idx < 0 || idx >= adim) return;
    int t = u;
    long off = idx * astride;
    DIM(0) DIM(1) DIM(2) DIM(3) DIM(4) DIM(5) DIM(6) DIM(7)
    volatile __global uint *p = acc + off;
    const float v = (float)LD(updates, u);
#if RED == RED_NONE
    atomic_xchg(p, as_uint(v));
#elif RED == RED_MAX
    atomic_max(p, float_key(as_uint(v)));
#elif RED == RED_MIN
    atomic_min(p, float_key(as_uint(v)));
#else
    /* Start from an atomic read: a plain load would race with the other updates. */
    uint old = atomic_or(p, 0u);
    for (;;) {
#if RED == RED_ADD
        const uint want = as_uint(as_float(old) + v);
#else
        const uint want = as_uint(as_float(old) * v);
#endif
        const uint seen = atomic_cmpxchg(p, old, want);
        if (seen == old) break;
        old = seen;
    }
#endif
}

/* FSR2 previous-depth reconstruction. Pixel (x, y) of depth [N,1,H,W] moved to
 * (x + mx, y + my) in pixel-index space (motion [N,2,H,W], render pixels). Its depth
 * goes to each of the 4 bilinear taps around that point whose bilinear weight exceeds
 * wmin (FSR2: 0.01) and that lie on screen, combined with atomic max (reversed-Z,
 * nearest = largest) or min. buf [N,1,H,W] holds float bits, cleared beforehand to the
 * far plane, the identity of the reduction. Negative or NaN depths are not scattered
 * (their bits would not order), and -0 is stored as +0. */
/** @param[in]  depth   [N, 1, H, W] depth (reversed-Z by default)
 *  @param[in]  motion  [N, 2, H, W] motion in render pixels
 *  @param[out] buf     [N, 1, H, W] float bits, cleared beforehand to the far plane
 *  @param[in]  H       height
 *  @param[in]  W       width
 *  @param[in]  N       batch
 *  @param[in]  wmin    bilinear weight a tap must exceed to receive the depth (FSR2: 0.01)
 *  @note -DDEPTH_MAX=0|1: keep the min or the max (reversed-Z: nearest = max)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void scatter_depth(__global const T *depth, __global const T *motion, __global uint *buf,
                            int H, int W, int N, float wmin)
{
    const int x = get_global_id(0), y = get_global_id(1), n = get_global_id(2);
    if (x >= W || y >= H || n >= N) return;
    const long HW = (long)H * W;
    const long pix = (long)y * W + x;
    const float d = (float)LD(depth, n * HW + pix);
    if (!(d >= 0.0f)) return;
    const uint bits = d == 0.0f ? 0u : as_uint(d);
    const float mx = (float)LD(motion, 2 * n * HW + pix);
    const float my = (float)LD(motion, (2 * n + 1) * HW + pix);
    const float px = (float)x + mx, py = (float)y + my;
    const float bx = floor(px), by = floor(py);
    /* Every tap off screen, or a NaN/huge motion: nothing to store (and no int overflow). */
    if (!(bx >= -1.0f && bx < (float)W && by >= -1.0f && by < (float)H)) return;
    const float fx = px - bx, fy = py - by;
    const int ix = (int)bx, iy = (int)by;
    const float w[4] = {(1.0f - fx) * (1.0f - fy), fx * (1.0f - fy), (1.0f - fx) * fy, fx * fy};
    volatile __global uint *b = buf + n * HW;
    for (int k = 0; k < 4; ++k) {
        const int tx = ix + (k & 1), ty = iy + (k >> 1);
        if (w[k] > wmin && tx >= 0 && tx < W && ty >= 0 && ty < H) {
#if DEPTH_MAX
            atomic_max(b + (long)ty * W + tx, bits);
#else
            atomic_min(b + (long)ty * W + tx, bits);
#endif
        }
    }
}
