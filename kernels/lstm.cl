/* The pointwise half of a ConvLSTM cell (Shi et al. 2015), in one pass: from the gate
 * pre-activations one convolution wrote and the previous cell state c,
 *
 *     c' = sigmoid(f) * c + sigmoid(i) * tanh(g)        h' = sigmoid(o) * tanh(c')
 *
 * The ONNX graph writes it as a Split of the gates, three Sigmoid, two Tanh, three Mul and
 * an Add: ten kernels and ten passes over memory, which on NSRD's network took as long as
 * its largest convolution (clss/model/passes.py fuse_lstm_cell makes them one
 * clss.LSTMCell node). The same operations in the same order as those nodes: FP_CONTRACT
 * off (the Mul and Add were separate kernels), sigmoid and tanh in the 8-wide forms of
 * the elementwise kernel, and every intermediate rounded to the storage precision as the
 * unfused graph stores it, so the fused cell matches the ten kernels bit for bit.
 *
 * The gates come as NCHW [N, 4C, H, W] or, with -DGATE_BLOCK=V, in the channel-blocked
 * layout a conv2d_blocked writes ([N, CB, H, W, V], clss/model/layout.py): the gate
 * convolution then stores its accumulators whole instead of transposing 4C channel planes.
 * c, h' and c' are NCHW [N, C, H, W].
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#ifndef GATE_BLOCK
#define GATE_BLOCK 0
#endif

/* pixels per work-item (a multiple of 8) */
#ifndef CELL_PX
#define CELL_PX 64
#endif


/* An intermediate as the unfused graph keeps it: stored in T, read back as A. */
#if defined(CLSS_FP16)
static A8 as_stored8(A8 v)
{
    ushort t[8];                /* half arrays need cl_khr_fp16; a half pointer does not */
    vstore_half8_rte(v, 0, (__private half *)t);
    return vload_half8(0, (__private const half *)t);
}
#else
static A8 as_stored8(A8 v)
{
    return v;
}
#endif

/* Element offsets of gate channel k*C + ch at pixel p0 (GATE_AT) and between pixels
 * (GATE_STEP): one lane of consecutive pixel blocks when blocked, a plane row if not. */
#if GATE_BLOCK
#define GATE_AT(k) ((((long)n * CB + ((k) * C + ch) / GATE_BLOCK) * HW + p0) * GATE_BLOCK \
                    + ((k) * C + ch) % GATE_BLOCK)
#define GATE_STEP GATE_BLOCK
#define GATE8(a) ((A8)(FLD(gates, (a)), FLD(gates, (a) + GATE_STEP), FLD(gates, (a) + 2 * GATE_STEP), \
                       FLD(gates, (a) + 3 * GATE_STEP), FLD(gates, (a) + 4 * GATE_STEP),             \
                       FLD(gates, (a) + 5 * GATE_STEP), FLD(gates, (a) + 6 * GATE_STEP),             \
                       FLD(gates, (a) + 7 * GATE_STEP)))
#else
#define GATE_AT(k) (((long)n * 4 * C + (k) * C + ch) * HW + p0)
#define GATE_STEP 1
#define GATE8(a) FLD8(gates, (a))
#endif

/* NDRange: (ceil(H * W / CELL_PX), N). A work-item takes every channel of CELL_PX pixels. */
/** @param[in]  gates  [N, 4C, H, W] gate pre-activations, or blocked [N, CB, H, W, GATE_BLOCK]
 *  @param[in]  c      [N, C, H, W] the previous cell state
 *  @param[out] h_out  [N, C, H, W] the new hidden state h'
 *  @param[out] c_out  [N, C, H, W] the new cell state c'
 *  @param[in]  C      channels of the state
 *  @param[in]  HW     H * W
 *  @param[in]  ki     which quarter of the gates' channels holds i (0..3)
 *  @param[in]  kf     ... f
 *  @param[in]  ko     ... o
 *  @param[in]  kg     ... g
 *  @param[in]  CB     blocks of the gates (blocked layout; unused for NCHW)
 *  @note -DGATE_BLOCK=0|V: NCHW gates | channel-blocked gates in blocks of V
 *  @note -DCELL_PX: pixels per work-item (a multiple of 8)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h)
 */
__kernel void lstm_cell(__global const T *gates, __global const T *c, __global T *h_out,
                        __global T *c_out, int C, int HW, int ki, int kf, int ko, int kg, int CB)
{
    const int q0 = get_global_id(0) * CELL_PX, n = get_global_id(1);
    if (q0 >= HW) return;
    /* every channel of CELL_PX pixels in one work-item, channel by channel: each channel
     * streams through its planes of c, h' and c' (8 pixels a step), and the blocked gates
     * of these pixels (CELL_PX * 4 * 64 bytes) stay in L1 from one channel to the next */
    for (int ch = 0; ch < C; ++ch) {
        for (int p0 = q0; p0 < min(q0 + CELL_PX, HW); p0 += 8) {
            const int np = min(8, HW - p0);
            const long ai = GATE_AT(ki), af = GATE_AT(kf), ao = GATE_AT(ko), ag = GATE_AT(kg);
            const long o = ((long)n * C + ch) * HW + p0;
            A8 vi, vf, vo, vg, cv;
            if (np == 8) {
                vi = GATE8(ai);
                vf = GATE8(af);
                vo = GATE8(ao);
                vg = GATE8(ag);
                cv = FLD8(c, o);
            } else {
                A t[5][8];      /* lanes past the end repeat the last pixel (not stored) */
                for (int j = 0; j < 8; ++j) {
                    const int e = min(j, np - 1);
                    t[0][j] = FLD(gates, ai + (long)e * GATE_STEP);
                    t[1][j] = FLD(gates, af + (long)e * GATE_STEP);
                    t[2][j] = FLD(gates, ao + (long)e * GATE_STEP);
                    t[3][j] = FLD(gates, ag + (long)e * GATE_STEP);
                    t[4][j] = FLD(c, o + e);
                }
                vi = vload8(0, t[0]);
                vf = vload8(0, t[1]);
                vo = vload8(0, t[2]);
                vg = vload8(0, t[3]);
                cv = vload8(0, t[4]);
            }
            const A8 si = as_stored8(SIGMOID(vi));
            const A8 sf = as_stored8(SIGMOID(vf));
            const A8 so = as_stored8(SIGMOID(vo));
            const A8 tg = as_stored8(tanh(vg));
            const A8 m1 = as_stored8(sf * cv);
            const A8 m2 = as_stored8(si * tg);
            const A8 cn = as_stored8(m1 + m2);
            const A8 tc = as_stored8(tanh(cn));
            const A8 hn = so * tc;
            if (np == 8) {
                FST8(c_out, o, cn);
                FST8(h_out, o, hn);
            } else {
                A cs[8], hs[8];
                vstore8(cn, 0, cs);
                vstore8(hn, 0, hs);
                for (int j = 0; j < np; ++j) {
                    FST(c_out, o + j, cs[j]);
                    FST(h_out, o + j, hs[j]);
                }
            }
        }
    }
}
