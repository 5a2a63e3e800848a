"""The ConvLSTM cell's pointwise half in one kernel (kernels/lstm.cl): the gates'
sigmoids and tanh, the new cell state and the new hidden state from one pass over the
gate pre-activations. clss.Model makes it of the ONNX nodes that spell it out
(clss/model/passes.py fuse_lstm_cell); its twin is those nodes."""
from __future__ import annotations

import numpy as np

from ..device import Device
from .base import check_storage
from .conv import builtin_free

GATES = ("i", "f", "o", "g")
CELL_PX = 64       # pixels per work-item (kernels/lstm.cl)


def lstm_cell(dev: Device, prec: str, gates, c, order=(0, 1, 2, 3), h_out=None, c_out=None):
    """c' = sigmoid(f) * c + sigmoid(i) * tanh(g), h' = sigmoid(o) * tanh(c'); returns
    (h', c'). gates: [N, 4C, H, W] (NCHW), or the channel-blocked [N, CB, H, W, V] a blocked
    conv writes (clss/model/layout.py); c: [N, C, H, W]. order: which quarter of the
    gates' channels holds i, f, o and g (an ONNX Split's outputs, in the graph's order)."""
    check_storage("gates", gates, prec)
    check_storage("c", c, prec)
    if c.ndim != 4:
        raise ValueError(f"lstm_cell: c must be [N, C, H, W], got {tuple(c.shape)}")
    n, ch, h, w = c.shape
    blocked = gates.ndim == 5
    if blocked:
        gn, cb, gh, gw, v = gates.shape
        ok = cb * v >= 4 * ch and cb == -(-4 * ch // v)
    else:
        gn, gc, gh, gw = gates.shape
        cb, v, ok = 0, 0, gc == 4 * ch
    if not ok or (gn, gh, gw) != (n, h, w):
        raise ValueError(f"lstm_cell: gates {tuple(gates.shape)} do not hold 4 x {ch} channels of "
                         f"[N={n}, H={h}, W={w}]")
    if sorted(order) != [0, 1, 2, 3]:
        raise ValueError(f"lstm_cell: order must be a permutation of 0..3, got {order}")
    h_out = h_out if h_out is not None else dev.empty(c.shape, prec)
    c_out = c_out if c_out is not None else dev.empty(c.shape, prec)
    k = dev.kernel("lstm", "lstm_cell", prec, GATE_BLOCK=v, CELL_PX=CELL_PX, CLSS_CLANG_VECTORS=builtin_free(dev))
    hw = h * w
    dev.launch(k, (-(-hw // CELL_PX), n),
               (gates.data, c.data, h_out.data, c_out.data, np.int32(ch), np.int32(hw),
                *(np.int32(o) for o in order), np.int32(cb)))
    return h_out, c_out
