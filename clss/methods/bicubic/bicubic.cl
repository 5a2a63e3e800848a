/* The plain bicubic baseline's frame step around clss.ops.resize (the room
 * clss/methods/bicubic/; its ONNX twin oracle.py states the same formulas as graph nodes):
 *
 *   bicubic_encode  the caller's colour (image layout, float32 linear) -> PQ [3,h,w] (T)
 *   (resize)        Keys cubic, a = -0.75, half-pixel centres, on the PQ planes
 *   bicubic_decode  PQ [3,H,W] (T) -> the caller's image, linear (the code value clamped
 *                   to [0, 1] first, as the twin's Clip)
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#include "pq.h"

/** @param[in]  color        [h,w,3] float32 linear
 *  @param[out] x            [3,h,w] T: PQ code values of colour / exposure
 *  @param[in]  h            render height
 *  @param[in]  w            render width
 *  @param[in]  inv_exposure 1 / exposure
 *  @param[in]  pq_scale     nits / 10000
 *  NDRange: (w, h). */
__kernel void bicubic_encode(__global const float *color, __global T *x, int h, int w,
                             float inv_exposure, float pq_scale)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= w || py >= h) return;
    const long plane = (long)h * w, p = (long)py * w + px;
    for (int c = 0; c < 3; ++c)
        ST(x, c * plane + p, pq_encode(color[3 * p + c] * inv_exposure, pq_scale));
}

/** @param[in]  y            [3,H,W] T: the resized PQ code values
 *  @param[out] out          [H,W,3] float32 linear
 *  @param[in]  H            output height
 *  @param[in]  W            output width
 *  @param[in]  inv_pq_scale 10000 / nits, times the exposure
 *  NDRange: (W, H). */
__kernel void bicubic_decode(__global const T *y, __global float *out, int H, int W,
                             float inv_pq_scale)
{
    const int X = get_global_id(0), Y = get_global_id(1);
    if (X >= W || Y >= H) return;
    const long plane = (long)H * W, p = (long)Y * W + X;
    for (int c = 0; c < 3; ++c)
        out[3 * p + c] = pq_decode(LD(y, c * plane + p), inv_pq_scale);
}
