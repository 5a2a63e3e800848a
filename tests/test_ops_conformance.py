"""Every op family's conformance cases (clss/verify/cases/<family>.py `cases("full")`, what
`clss verify --level full` runs) against onnxruntime, in fp32 and fp16, on every OpenCL
device under test (conftest.any_dev). The per-family behaviour beyond the cases (argument
checks, hypothesis-drawn parameters, fast paths) is in tests/test_ops_<family>.py.

The default device runs every case; the other devices (the second compiler) run the quick
cases of every family (`clss verify`'s default level) in the default tier and the rest in
the slow one (conftest, `slow_on_other_devices`): the full sweep on both PoCLs was a fifth
of CI's time."""
import pytest

from clss.ops import FAMILIES
from clss.verify.cases import family
from helpers import PRECISIONS, assert_case

CASES = [(name, case) for name in FAMILIES for case in family(name).cases("full")]
QUICK = {(name, case.name) for name in FAMILIES for case in family(name).cases("quick")}


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("case", [
    pytest.param(c, id=f"{f}/{c.name}",
                 marks=() if (f, c.name) in QUICK else pytest.mark.slow_on_other_devices)
    for f, c in CASES])
def test_against_onnxruntime(case, precision, any_dev):
    assert_case(case, any_dev, precision)
