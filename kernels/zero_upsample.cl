/* Zero-upsampling (NSRR, Xiao et al. 2020, section 3.2.2): each render-resolution sample
 * is placed at the output pixel that contains it, every other output pixel is zero.
 * Pure data movement: samples are copied as raw bits (TB), bit-exact in every precision.
 *
 * Placement along one axis (scale s >= 1, jitter j_ in render pixels, in [-0.5, 0.5]):
 * the sample of render index j was taken at j + 0.5 + j_ render pixels, i.e. at
 * p = (j + 0.5 + j_) * s output pixels, and goes to output index
 *     X(j) = min(floor(p), ceil((j + 1) * s) - 1)
 * (a sample on its render pixel's far edge, j_ = +0.5, stays inside that pixel's
 * footprint). Integer s takes the exact integer form X(j) = j*s + o with the offset
 * o = min(floor((0.5 + j_) * s), s - 1) computed by the host, so large images do not
 * depend on float rounding; other s use the float32 form above (the host mirrors it
 * operation by operation for the twin). Samples landing outside the output are dropped.
 *
 * The kernel gathers: each output pixel finds the (at most one, since s >= 1) render
 * index mapping onto it, so every output element is written exactly once, zeros
 * included, with no races and no separate clear.
 *
 * Build options: -DCPT=n channels per work-item (default 4), reusing the index search.
 * NDRange: (output width, output height, N * ceil(C / CPT)).
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#ifndef CPT
#define CPT 4
#endif

#include "zero_upsample.h"

/** @param[in]  in   [N, C, h, w] render-resolution samples, moved as raw bits (TB)
 *  @param[out] out  [N, C, Ho, Wo] output, zero where no sample lands
 *  @param[in]  C    channels
 *  @param[in]  h    input height
 *  @param[in]  w    input width
 *  @param[in]  Ho   output height
 *  @param[in]  Wo   output width
 *  @param[in]  NCb  N * ceil(C / CPT), the extent of NDRange dimension 2
 *  @param[in]  siy  integer scale along y, or 0 for a non-integer one (then sy is used)
 *  @param[in]  six  integer scale along x, or 0
 *  @param[in]  oy   integer-scale offset along y, min(floor((0.5 + jy) * siy), siy - 1), from the host
 *  @param[in]  ox   integer-scale offset along x
 *  @param[in]  sy   scale along y (non-integer form)
 *  @param[in]  sx   scale along x (non-integer form)
 *  @param[in]  jy   jitter along y in render pixels, in [-0.5, 0.5]
 *  @param[in]  jx   jitter along x in render pixels
 *  @note -DCPT=n: channels per work-item (default 4)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void zero_upsample(__global const TB *in, __global TB *out,
                            int C, int h, int w, int Ho, int Wo, int NCb,
                            int siy, int six, int oy, int ox, float sy, float sx, float jy, float jx)
{
    const int X = get_global_id(0), Y = get_global_id(1), ncb = get_global_id(2);
    if (X >= Wo || Y >= Ho || ncb >= NCb) return;
    const int CB = (C + CPT - 1) / CPT;
    const int n = ncb / CB, c0 = (ncb % CB) * CPT;
    const int nc = min(CPT, C - c0);
    const long plane = (long)h * w, oplane = (long)Ho * Wo;
    const long o = ((long)n * C + c0) * oplane + (long)Y * Wo + X;
    const int i = zu_source(Y, h, siy, oy, sy, jy);
    const int j = i < 0 ? -1 : zu_source(X, w, six, ox, sx, jx);
    if (j < 0) {
        for (int c = 0; c < nc; ++c) out[o + c * oplane] = (TB)0;
        return;
    }
    __global const TB *src = in + ((long)n * C + c0) * plane + (long)i * w + j;
    for (int c = 0; c < nc; ++c) out[o + c * oplane] = src[c * plane];
}
