import numpy as np
import pytest

from clss.ops import mlp
from clss.verify.cases import mlp as mlp_cases


def test_packed_weights_reused_and_equal_to_layer_list(dev):
    g = np.random.default_rng(3)
    x = g.standard_normal((2, 4, 5, 9)).astype(np.float32)
    layers = [(g.standard_normal((6, 4)).astype(np.float32), None, "relu"),
              (g.standard_normal((2, 6, 1, 1)).astype(np.float32), g.standard_normal(2).astype(np.float32),
               ("leaky_relu", 0.3))]
    net = mlp.pack(dev, "fp32", layers)
    assert net.widths == (4, 6, 2)
    xd = dev.to_device(x)
    a = mlp.mlp(dev, "fp32", xd, net).get()
    b = mlp.mlp(dev, "fp32", xd, layers).get()
    assert np.array_equal(a, b)
    h = np.maximum(np.einsum("oc,nchw->nohw", layers[0][0], x), 0)
    y = np.einsum("oc,nchw->nohw", layers[1][0][:, :, 0, 0], h) + layers[1][1][None, :, None, None]
    y = np.where(y >= 0, y, 0.3 * y)
    np.testing.assert_allclose(a, y, rtol=1e-5, atol=1e-5)


def test_xv2_block_matches(dev):
    case = mlp_cases.make_case((22, 32, 1), ("relu", "sigmoid"), h=7, w=13)
    xd = dev.to_device(case.inputs["x"])
    ls = [(case.inputs[f"w{i}"], case.inputs[f"b{i}"], a) for i, a in enumerate(("relu", "sigmoid"))]
    a = mlp.mlp(dev, "fp32", xd, ls).get()
    b = mlp.mlp(dev, "fp32", xd, ls, tuning={"XV": 2}).get()
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)


def test_limits_and_bad_layers_raise(dev):
    x = dev.to_device(np.zeros((1, 3, 2, 2), np.float32))
    with pytest.raises(ValueError, match="exceed 128"):
        mlp.pack(dev, "fp32", [(np.zeros((129, 3), np.float32), None, "relu")])
    with pytest.raises(ValueError, match="takes 4 inputs"):
        mlp.pack(dev, "fp32", [(np.zeros((5, 3), np.float32), None, "relu"),
                               (np.zeros((2, 4), np.float32), None, "none")])
    with pytest.raises(ValueError, match="activation"):
        mlp.pack(dev, "fp32", [(np.zeros((5, 3), np.float32), None, "gelu")])
    with pytest.raises(ValueError, match="input has 3 channels"):
        mlp.mlp(dev, "fp32", x, [(np.zeros((5, 4), np.float32), None, "relu")])
    net = mlp.pack(dev, "fp16", [(np.zeros((5, 3), np.float32), None, "relu")])
    with pytest.raises(ValueError, match="packed for fp16"):
        mlp.mlp(dev, "fp32", x, net)
