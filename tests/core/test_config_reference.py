"""The configuration reference of the documentation site is generated from the configuration
classes: every key a user can write is in it, with its type, default and a description."""

import dataclasses
from dataclasses import dataclass, field

from safeswitch.core.config import fields_of, reference, sections
from safeswitch.leftturn.config import TrafficConfig
from safeswitch.training.config import EnvTrainConfig, TrainConfig


def test_every_configuration_key_is_documented():
    undocumented = [
        f"{key or section.__name__}.{f.name}"
        for root in (TrainConfig, TrafficConfig, EnvTrainConfig)
        for key, section in sections(root)
        for f in fields_of(section)
        if not f.description
    ]
    assert undocumented == []


def test_the_reference_names_every_key_of_the_tree_once_per_section():
    text = reference(TrainConfig, "training")
    for key, section in sections(TrainConfig):
        assert f"`{section.__name__}`" in text
        for f in dataclasses.fields(section):
            assert f"| `{f.name}` |" in text, f"{key}.{f.name}"
    assert "``" not in text and ":class:" not in text  # reStructuredText turned into Markdown


@dataclass(frozen=True)
class Inner:
    """Inner.

    Attributes:
        speed: How fast [m/s], a description
            that runs over two lines.
    """

    speed: float = 1.5


@dataclass(frozen=True)
class Outer:
    """Outer.

    Attributes:
        inner: The inner section.
        names: Names.

    Raises:
        ValueError: Never part of the attributes.
    """

    inner: Inner = field(default_factory=Inner)
    names: tuple[str, ...] = ("a",)
    missing: bool | None = None


def test_descriptions_defaults_and_sections_are_read_from_the_classes():
    assert sections(Outer) == [("", Outer), ("inner", Inner)]
    outer = {f.name: f for f in fields_of(Outer)}
    assert outer["inner"].default == "(section)"
    assert outer["names"].default == "['a']" and outer["names"].description == "Names."
    assert outer["missing"].default == "null" and outer["missing"].description == ""
    (speed,) = fields_of(Inner)
    assert speed.description == "How fast [m/s], a description that runs over two lines."
    assert speed.default == "1.5" and speed.type == "float"
