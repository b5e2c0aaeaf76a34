"""estimators.command: the command template's placeholders (check and expansion)."""
from __future__ import annotations

import pytest

from estimators.command import check_template, expand
from estimators.contract import ContractViolation

VALUES = {"images": ["a.png", "b.png", "c.png"], "measurements": "m.json", "output": "out.json", "camera": "cam.toml",
          "image1": "a.png", "image3": "c.png"}


def test_known_placeholders_pass_and_unknown_ones_are_named():
    assert check_template(["est", "--m={measurements}", "{images}", "{image2}", "--out", "{output}"]) == ""
    problem = check_template(["est", "{colour}"])
    assert problem.startswith("[1] = '{colour}' uses an unknown placeholder {colour}")
    assert "{images} must be a whole argument" in check_template(["est", "--in={images}"])


def test_expand_gives_one_argument_per_image_and_substitutes_inside_arguments():
    command = expand(["est", "{images}", "--camera={camera}", "{image3}", "{output}"], VALUES)
    assert command == ["est", "a.png", "b.png", "c.png", "--camera=cam.toml", "c.png", "out.json"]
    with pytest.raises(ContractViolation, match=r"no value for \{flat_field\} \(3 images\)"):
        expand(["est", "{flat_field}"], VALUES)
