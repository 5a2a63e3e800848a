/* conv_epilogue.h: the fused epilogue of one conv output, as conv2d's (kernels/conv.cl), shared
 * by the kernels that store conv outputs one value at a time (conv_gemm.cl's implicit GEMM,
 * conv_winograd_gemm.cl's output transform), so that every row of the conv variant table rounds
 * the same sums alike: v = acc + bias; + residual before the activation; act; + residual after. */
#ifndef CLSS_CONV_EPILOGUE_H
#define CLSS_CONV_EPILOGUE_H

#define F_BIAS 1
#define F_RES_BEFORE 2
#define F_RES_AFTER 4

/* The fused epilogue of one output value at element o of y. */
inline void store_out(__global T *y, __global const T *res, long o, A v, A b, int flags, float alpha)
{
    v += b;
    if (flags & F_RES_BEFORE)
        v += LD(res, o);
    v = APPLY_ACT(v, alpha);
    if (flags & F_RES_AFTER)
        v += LD(res, o);
    ST(y, o, v);
}

#endif
