/* conv_winograd_gemm: the two transforms of Winograd F(2x2, 3x3) on NCHW around a GEMM, the
 * winograd_gemm row of the conv2d variant table (clss/ops/conv_winograd_gemm.py).
 *
 * Per 2x2 output tile, Y = A^T [sum over c of U[c] (.) V[c]] A, with U = G g G^T the weights
 * (transformed once, on the host) and V = B^T d B of the 4x4 input tile d (stride 2). Element e
 * (of 16) of the sum over c is a GEMM, M[e] = U[e] V[e] (Cout x Cin times Cin x P), and the 16 of
 * them are one grouped 1x1 conv (16 groups) that conv_gemm.cl's conv2d_gemm computes, on any of
 * its inner products (local memory, global memory, tensor cores). This file holds the rest:
 *
 *   winograd_input   x [N][Cin][H][W] (zero in the padding) -> V [N][16][Cin][P]
 *   winograd_output  M [N][16][Cout][P] -> y [N][Cout][Ho][Wo], with conv2d's epilogue
 *
 * P = TH * TW tiles per image; tile p = ty * TW + tx covers output rows 2ty, 2ty + 1 and columns
 * 2tx, 2tx + 1 (the last row and column of tiles are partial at odd Ho, Wo). One work-item per
 * (tile, channel): consecutive work-items take consecutive tiles, so V and M are read and written
 * in runs along P, as the GEMM reads and writes them.
 *
 * V and M hold floats (-DMID_HALF=0): the sums of the transforms cancel, and rounding V and M to
 * half cost more than the precision's tolerance; or half storage (-DMID_HALF=1), what the
 * tensor-core GEMM takes. The arithmetic is A (common.h). */
#include "common.h"
#include "conv_epilogue.h"   /* store_out: bias, residual, activation */

#ifndef MID_HALF
#define MID_HALF 0
#endif
#if MID_HALF
typedef half MT;
#define MLD(p, i) vload_half((i), (p))
#define MST(p, i, v) vstore_half_rte((v), (i), (p))
#else
typedef float MT;
#define MLD(p, i) ((A)(p)[(i)])
#define MST(p, i, v) ((p)[(i)] = (float)(v))
#endif

/** V = B^T d B. NDRange (TW rounded up, TH, N * Cin).
 * @param[in]  x    [N, Cin, H, W] input
 * @param[out] v    [N, 16, Cin, TH * TW] transformed tiles, MT
 * @param[in]  Cin  input channels
 * @param[in]  H    input height
 * @param[in]  W    input width
 * @param[in]  TH   tile rows: ceil(Ho / 2)
 * @param[in]  TW   tile columns: ceil(Wo / 2)
 * @param[in]  pt   top pad
 * @param[in]  pl   left pad
 * @note -DMID_HALF=0|1: V as float / half storage; -DCLSS_FP16 / -DCLSS_FP16_NATIVE: x's storage (common.h) */
__kernel void winograd_input(__global const T *x, __global MT *v, int Cin, int H, int W, int TH, int TW,
                             int pt, int pl)
{
    const int tx = get_global_id(0), ty = get_global_id(1), z = get_global_id(2);
    if (tx >= TW)
        return;
    const int c = z % Cin, n = z / Cin;
    const __global T *xc = x + ((long)n * Cin + c) * H * W;
    const int y0 = 2 * ty - pt, x0 = 2 * tx - pl;
    A t[4][4];              /* B^T d: row i of it from rows 0..3 of d */
    for (int j = 0; j < 4; ++j) {
        const int ix = x0 + j;
        A d[4];
        for (int i = 0; i < 4; ++i) {
            const int iy = y0 + i;
            d[i] = (iy >= 0 && iy < H && ix >= 0 && ix < W) ? LD(xc, (long)iy * W + ix) : A_ZERO;
        }
        t[0][j] = d[0] - d[2];
        t[1][j] = d[1] + d[2];
        t[2][j] = d[2] - d[1];
        t[3][j] = d[1] - d[3];
    }
    const long P = (long)TH * TW, es = (long)Cin * P;       /* es: from element e to e + 1 */
    __global MT *vo = v + ((long)n * 16 * Cin + c) * P + (long)ty * TW + tx;
    for (int i = 0; i < 4; ++i) {   /* (B^T d) B: the same combination along the row */
        MST(vo, (4 * i + 0) * es, t[i][0] - t[i][2]);
        MST(vo, (4 * i + 1) * es, t[i][1] + t[i][2]);
        MST(vo, (4 * i + 2) * es, t[i][2] - t[i][1]);
        MST(vo, (4 * i + 3) * es, t[i][1] - t[i][3]);
    }
}

/** Y = A^T M A and the epilogue. NDRange (TW rounded up, TH, N * Cout).
 * @param[in]  m      [N, 16, Cout, TH * TW] the GEMM's products, MT
 * @param[in]  bias   [Cout] bias (read when flags has 1)
 * @param[in]  res    [N, Cout, Ho, Wo] residual (read when flags has 2 or 4)
 * @param[out] y      [N, Cout, Ho, Wo] output
 * @param[in]  Cout   output channels
 * @param[in]  Ho     output height
 * @param[in]  Wo     output width
 * @param[in]  TH     tile rows: ceil(Ho / 2)
 * @param[in]  TW     tile columns: ceil(Wo / 2)
 * @param[in]  flags  1 bias, 2 residual added before the activation, 4 after it
 * @param[in]  alpha  the activation's parameter (leaky_relu slope)
 * @note -DMID_HALF=0|1: M as float / half storage; -DACT: the fused activation
 * @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: y's storage (common.h) */
__kernel void winograd_output(__global const MT *m, __global const T *bias, __global const T *res, __global T *y,
                              int Cout, int Ho, int Wo, int TH, int TW, int flags, float alpha)
{
    const int tx = get_global_id(0), ty = get_global_id(1), z = get_global_id(2);
    if (tx >= TW)
        return;
    const int k = z % Cout, n = z / Cout;
    const long P = (long)TH * TW, es = (long)Cout * P;
    const __global MT *mo = m + ((long)n * 16 * Cout + k) * P + (long)ty * TW + tx;
    A t[2][4];              /* A^T M: rows 0..3 of M combined into two */
    for (int j = 0; j < 4; ++j) {
        const A m0 = MLD(mo, j * es), m1 = MLD(mo, (4 + j) * es), m2 = MLD(mo, (8 + j) * es),
                m3 = MLD(mo, (12 + j) * es);
        t[0][j] = m0 + m1 + m2;
        t[1][j] = m1 - m2 - m3;
    }
    const A b = (flags & F_BIAS) ? LD(bias, k) : A_ZERO;
    const long yoff = ((long)n * Cout + k) * Ho * Wo;
    for (int i = 0; i < 2; ++i) {   /* (A^T M) A */
        const int oy = 2 * ty + i, ox = 2 * tx;
        if (oy >= Ho)
            break;
        const long o = yoff + (long)oy * Wo + ox;
        store_out(y, res, o, t[i][0] + t[i][1] + t[i][2], b, flags, alpha);
        if (ox + 1 < Wo)
            store_out(y, res, o + 1, t[i][1] - t[i][2] - t[i][3], b, flags, alpha);
    }
}
