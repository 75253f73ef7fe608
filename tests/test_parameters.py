"""The parameter registry: one place that the deformer, the quantiser, the layouts and the docs read."""

from pathlib import Path

import numpy as np
import pytest

from facedeform.common.parameters import EXTENDED_PARAMS, LAYOUTS, PARAMETERS, STEPS, slots, span, table
from facedeform.protocol.header import Header, encode_header, parse_header
from facedeform.protocol.quantise import steps_for

DOCS = Path(__file__).resolve().parents[1] / "docs" / "parameters.md"


def test_slots_follow_the_full_vector_and_every_layout_is_registered():
    assert [PARAMETERS[n].slot for n in EXTENDED_PARAMS] == list(range(len(EXTENDED_PARAMS)))
    for layout, names in LAYOUTS.items():
        assert all(layout in PARAMETERS[n].layouts for n in names)
    assert PARAMETERS["basis_0"].layouts == ("personal",) and PARAMETERS["gx"].layouts == ()


def test_the_quantiser_takes_each_step_from_the_registry_halving_per_level():
    names = ("theta", "v2x", "lid_l", "gr", "basis_3")
    np.testing.assert_array_equal(steps_for(names), [STEPS["angle"], STEPS["length"], STEPS["lid"],
                                                     STEPS["angle"], STEPS["length"]])
    np.testing.assert_array_equal(steps_for(names, 5), steps_for(names) / 4)


def test_caller_mistakes_are_value_errors():
    with pytest.raises(ValueError, match="'jaw'"):
        steps_for(("theta", "jaw"))
    with pytest.raises(ValueError, match="quality"):
        steps_for(("theta",), 7)
    with pytest.raises(ValueError, match="consecutive"):
        span(("theta", "rx"))
    with pytest.raises(KeyError):
        slots(("nose",))


def test_a_layout_the_registry_does_not_hold_keeps_its_written_steps():
    header = Header(25.0, ("theta", "custom"), np.array([0.25, 0.5]), "00" * 32)
    assert parse_header(encode_header(header)).names == ("theta", "custom")


def test_the_docs_table_is_the_registry():
    if not DOCS.exists():
        pytest.skip("no docs/ beside the tests")
    assert DOCS.read_text() == table(), "run docs/make_parameters_table.py"
