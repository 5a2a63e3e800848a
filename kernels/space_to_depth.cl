/* SpaceToDepth / DepthToSpace: pure data movement, bit-exact in every precision.
 *
 * Build options:
 *   -DCRD=0  DCR channel order: blocks outer, channels inner,
 *            channel (by*B + bx)*C + c  (ONNX SpaceToDepth, DepthToSpace mode=DCR)
 *   -DCRD=1  CRD order: channels outer, channel c*B*B + by*B + bx
 *            (ONNX DepthToSpace mode=CRD, PyTorch pixel_shuffle/pixel_unshuffle)
 *
 *   -DS2D_VEC=1 (default) B = 2 de-interleaves with 8-wide vector loads (the fast path);
 *   -DS2D_VEC=0  the portable reference: a scalar loop for every B.
 *   -DS2D_VEC=2  the fast path with its two output runs swapped: deliberately wrong,
 *                only for the test that proves the fast-path self-check refuses a
 *                wrong variant (tests/test_selfcheck.py; clss/selfcheck.py).
 *
 * Dimension 0 of each NDRange walks contiguous rows. Elements move as raw bits
 * (TB), so NaN payloads and signed zeros survive.
 */
#include "common.h"

#ifndef CRD
#define CRD 0
#endif
#ifndef S2D_VEC
#define S2D_VEC 1
#endif

/* Output channel of input channel c at block position (by, bx). */
inline int s2d_channel(int c, int by, int bx, int C, int B)
{
#if CRD
    return (c * B + by) * B + bx;
#else
    return (by * B + bx) * C + c;
#endif
}

/* in: [N, C, H*B, W*B] -> out: [N, C*B*B, H, W].
 * NDRange: (ceil(W / 8), H, N * C * B). A work-item takes 8 output columns of one
 * input row (c, y*B + by): it reads the 8*B contiguous input elements once and writes
 * B runs of 8 contiguous outputs, one per bx, so both sides stream through memory
 * (one element per work-item made every read a stride-B gather). B = 2, the CLSS
 * classifier's case, de-interleaves with vector loads; other B loop. */
/** @param[in]  in   [N, C, H*B, W*B] input, moved as raw bits (TB)
 *  @param[out] out  [N, C*B*B, H, W] output
 *  @param[in]  C    input channels
 *  @param[in]  H    output height (input height / B)
 *  @param[in]  W    output width (input width / B)
 *  @param[in]  B    block size
 *  @param[in]  NCB  N * C * B, the extent of NDRange dimension 2
 *  @note -DCRD=0|1: DCR or CRD channel order
 *  @note -DS2D_VEC=1|0|2: B = 2 vector de-interleave (fast path) | scalar reference | deliberately wrong (self-check test only)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void space_to_depth(__global const TB *in, __global TB *out,
                             int C, int H, int W, int B, int NCB)
{
    const int x0 = get_global_id(0) * 8, y = get_global_id(1), ncb = get_global_id(2);
    if (x0 >= W || y >= H || ncb >= NCB) return;
    const int by = ncb % B, nc = ncb / B, c = nc % C, n = nc / C;
    const long Wi = (long)W * B, plane = (long)H * W;
    __global const TB *row = in + ((long)nc * H * B + (long)y * B + by) * Wi + (long)x0 * B;
    __global TB *o = out + (long)n * C * B * B * plane + (long)y * W + x0;
#if S2D_VEC
    /* Two 8-wide loads, each de-interleaved into 4 lanes. Not one 16-wide
     * .even/.odd: PoCL 3.0-rc2 on AVX-512 returns garbage in lanes 4-7 of
     * uint16.even/.odd (ushort16 is right), a miscompile this form avoids. */
    if (B == 2 && x0 + 8 <= W) {
        const TB8 v0 = TB_LD8(row), v1 = TB_LD8(row + 8);
        const int bx_even = S2D_VEC == 2;   /* 0 but in the deliberately wrong variant */
        TB_ST8(o + s2d_channel(c, by, bx_even, C, 2) * plane, (TB8)(v0.even, v1.even));
        TB_ST8(o + s2d_channel(c, by, 1 - bx_even, C, 2) * plane, (TB8)(v0.odd, v1.odd));
        return;
    }
#endif
    const int nx = min(8, W - x0);
    for (int bx = 0; bx < B; ++bx) {
        __global TB *ob = o + s2d_channel(c, by, bx, C, B) * plane;
        for (int e = 0; e < nx; ++e)
            ob[e] = row[e * B + bx];
    }
}

/* in: [N, C*B*B, H, W] -> out: [N, C, H*B, W*B], the inverse of space_to_depth.
 * NDRange: (ceil(W / 8), H, N * C * B). A work-item takes 8 input columns of the B
 * input channels (c, by, bx = 0..B-1) and writes the 8*B contiguous outputs of output
 * row y*B + by they interleave into, so both sides stream through memory (one output
 * element per work-item, with B and the channel found by integer division, made it
 * 10x slower than a copy). B = 2 (NSRD's sub-pixel upsampling) interleaves two
 * vload8 into two vstore8; other B loop. */
/** @param[in]  in   [N, C*B*B, H, W] input, moved as raw bits (TB)
 *  @param[out] out  [N, C, H*B, W*B] output
 *  @param[in]  C    output channels
 *  @param[in]  H    input height
 *  @param[in]  W    input width
 *  @param[in]  B    block size
 *  @param[in]  NCB  N * C * B, the extent of NDRange dimension 2
 *  @note -DCRD=0|1: DCR or CRD channel order
 *  @note -DS2D_VEC=1|0|2: B = 2 vector interleave (fast path) | scalar reference | deliberately wrong (self-check test only)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void depth_to_space(__global const TB *in, __global TB *out,
                             int C, int H, int W, int B, int NCB)
{
    const int x0 = get_global_id(0) * 8, y = get_global_id(1), ncb = get_global_id(2);
    if (x0 >= W || y >= H || ncb >= NCB) return;
    const int by = ncb % B, nc = ncb / B, c = nc % C, n = nc / C;
    const long Wo = (long)W * B, plane = (long)H * W;
    __global const TB *src = in + (long)n * C * B * B * plane + (long)y * W + x0;
    __global TB *o = out + ((long)nc * H * B + (long)y * B + by) * Wo + (long)x0 * B;
#if S2D_VEC
    if (B == 2 && x0 + 8 <= W) {
        const int bx_even = S2D_VEC == 2;   /* 0 but in the deliberately wrong variant */
        const TB8 a = TB_LD8(src + s2d_channel(c, by, bx_even, C, 2) * plane);
        const TB8 b = TB_LD8(src + s2d_channel(c, by, 1 - bx_even, C, 2) * plane);
        TB_ST8(o, (TB8)(a.s0, b.s0, a.s1, b.s1, a.s2, b.s2, a.s3, b.s3));
        TB_ST8(o + 8, (TB8)(a.s4, b.s4, a.s5, b.s5, a.s6, b.s6, a.s7, b.s7));
        return;
    }
#endif
    const int nx = min(8, W - x0);
    for (int bx = 0; bx < B; ++bx) {
        __global const TB *ib = src + s2d_channel(c, by, bx, C, B) * plane;
        for (int e = 0; e < nx; ++e)
            o[e * B + bx] = ib[e];
    }
}
