/* Where a jittered render sample lands at output resolution (zero-upsampling), shared by
 * kernels/zero_upsample.cl and the frame kernels that place samples as it does. */
#ifndef ZERO_UPSAMPLE_H
#define ZERO_UPSAMPLE_H

/* the output index that render sample j (taken at j + 0.5 + jit) lands on at scale s */
static int zu_place(int j, float s, float jit)
{
    const float p = ((float)j + 0.5f + jit) * s;
    return min((int)floor(p), (int)ceil((float)(j + 1) * s) - 1);
}

/* The render index whose sample lands on output index X, or -1. si > 0: integer scale
 * with the host's offset o. */
static int zu_source(int X, int n, int si, int o, float s, float jit)
{
    if (si > 0) {
        const int d = X - o;
        if (d < 0 || d % si) return -1;
        return d / si < n ? d / si : -1;
    }
    /* The exact preimage lies within 0.5 of (X + 0.5)/s - 0.5 - jit; rounding and the
     * edge clamp move it by less than one more. */
    const int jc = (int)floor(((float)X + 0.5f) / s - 0.5f - jit);
    for (int j = max(jc - 1, 0); j <= min(jc + 1, n - 1); ++j)
        if (zu_place(j, s, jit) == X) return j;
    return -1;
}

#endif
