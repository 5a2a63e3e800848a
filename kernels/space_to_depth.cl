/* SpaceToDepth / DepthToSpace: pure data movement, bit-exact in every precision.
 *
 * Build options:
 *   -DCRD=0  DCR channel order: blocks outer, channels inner,
 *            channel (by*B + bx)*C + c  (ONNX SpaceToDepth, DepthToSpace mode=DCR)
 *   -DCRD=1  CRD order: channels outer, channel c*B*B + by*B + bx
 *            (ONNX DepthToSpace mode=CRD, PyTorch pixel_shuffle/pixel_unshuffle)
 *
 * NDRange: (output width, output height, N * output channels); dimension 0
 * walks the contiguous output row. Each work-item moves one element as raw
 * bits (TB), so NaN payloads and signed zeros survive.
 */
#include "common.h"

#ifndef CRD
#define CRD 0
#endif

/* in: [N, C, H*B, W*B] -> out: [N, C*B*B, H, W] */
__kernel void space_to_depth(__global const TB *in, __global TB *out,
                             int C, int H, int W, int B, int NCo)
{
    const int x = get_global_id(0), y = get_global_id(1), nc = get_global_id(2);
    if (x >= W || y >= H || nc >= NCo) return;
    const int Co = C * B * B;
    const int n = nc / Co, co = nc % Co;
#if CRD
    const int c = co / (B * B), by = (co / B) % B, bx = co % B;
#else
    const int c = co % C, by = (co / C) / B, bx = (co / C) % B;
#endif
    const long src = (((long)n * C + c) * (H * B) + (y * B + by)) * (long)(W * B) + (x * B + bx);
    out[((long)nc * H + y) * W + x] = in[src];
}

/* in: [N, C*B*B, H, W] -> out: [N, C, H*B, W*B] */
__kernel void depth_to_space(__global const TB *in, __global TB *out,
                             int C, int H, int W, int B, int NC)
{
    const int X = get_global_id(0), Y = get_global_id(1), nc = get_global_id(2);
    if (X >= W * B || Y >= H * B || nc >= NC) return;
    const int n = nc / C, c = nc % C;
    const int x = X / B, bx = X % B, y = Y / B, by = Y % B;
#if CRD
    const int ci = c * B * B + by * B + bx;
#else
    const int ci = (by * B + bx) * C + c;
#endif
    const long src = (((long)n * C * B * B + ci) * H + y) * (long)W + x;
    out[((long)nc * (H * B) + Y) * (W * B) + X] = in[src];
}
