"""Conformance cases of the fused ConvLSTM cell (clss/ops/lstm.py, kernels/lstm.cl): its
twin is the ONNX nodes it stands for (a Split of the gates, three Sigmoid, two Tanh, three
Mul and an Add), with the gates in any order."""
from __future__ import annotations

import numpy as np
from ...model.passes import lstm_cell_graph
from ...ops.base import rng
from ...ops.lstm import GATES, lstm_cell
from ..case import Case, host_call


def cell_model(x: np.ndarray, channels: int, *, conv: bool = False, order=(0, 1, 2, 3)):
    """The twin: the cell as ONNX nodes (clss.model.passes.lstm_cell_graph), inputs x (the
    gates, or with conv=True a 3x3 convolution's input) and c, outputs h and c_out."""
    return lstm_cell_graph(x.shape, channels, conv=conv, order=order)


def cases(level: str = "quick") -> list[Case]:
    shapes = [(1, 16, 5, 13, (0, 1, 2, 3)), (2, 3, 7, 9, (2, 0, 3, 1))]
    if level == "tiny":
        shapes = [(1, 4, 3, 5, (1, 3, 0, 2))]
    elif level == "full":
        shapes += [(1, 1, 1, 1, (3, 2, 1, 0)), (1, 8, 16, 16, (0, 1, 2, 3)), (1, 5, 11, 23, (1, 0, 2, 3))]
    out = []
    for n, ch, h, w, order in shapes:
        g = rng("lstm cell", n, ch, h, w, order)
        gates = (g.standard_normal((n, 4 * ch, h, w)) * 2).astype(np.float32)
        c = g.standard_normal((n, ch, h, w)).astype(np.float32)
        out.append(Case("lstm_cell", f"{n}x{ch}x{h}x{w} order {''.join(GATES[order.index(k)] for k in range(4))}",
                        {"x": gates, "c": c}, cell_model(gates, ch, order=order),
                        host_call(lambda dev, p, x, c, o=order: list(lstm_cell(dev, p, x, c, o)))))
    return out
