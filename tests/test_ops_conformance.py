"""Every op family's conformance cases (clss/verify/cases/<family>.py `cases("full")`, what
`clss verify --level full` runs) against onnxruntime, in fp32 and fp16, on every OpenCL
device under test (conftest.any_dev). The per-family behaviour beyond the cases (argument
checks, hypothesis-drawn parameters, fast paths) is in tests/test_ops_<family>.py."""
import pytest

from clss.ops import FAMILIES
from clss.verify.cases import family
from helpers import PRECISIONS, assert_case

CASES = [(name, case) for name in FAMILIES for case in family(name).cases("full")]


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("case", [c for _, c in CASES], ids=[f"{f}/{c.name}" for f, c in CASES])
def test_against_onnxruntime(case, precision, any_dev):
    assert_case(case, any_dev, precision)
