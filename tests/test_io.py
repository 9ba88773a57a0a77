"""Run outputs are written whole: an interrupt (Ctrl-C) or an error leaves the previous file or
snapshot and no temporary debris (a clean-clone CI once found a ``.000174.json.tmp`` left by a
campaign stopped between writing a shard and renaming it)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from safeswitch.io import replacing, write_atomic, write_snapshot


def test_a_file_is_replaced_only_when_written_whole(tmp_path):
    target = tmp_path / "shard.json"
    write_atomic(target, "old")
    with pytest.raises(KeyboardInterrupt), replacing(target) as tmp:
        tmp.write_text("half", encoding="utf-8")
        raise KeyboardInterrupt
    assert target.read_text(encoding="utf-8") == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shard.json"]
    with replacing(target) as tmp:
        tmp.write_text("new", encoding="utf-8")
    assert target.read_text(encoding="utf-8") == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shard.json"]


class _Saves:
    """Anything with ``save(path)``, as SB3's models and ``VecNormalize``; ``interrupt`` makes
    the save stop half-way."""

    def __init__(self, text: str, interrupt: bool = False) -> None:
        self.text, self.interrupt = text, interrupt

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.text[:2], encoding="utf-8")
        if self.interrupt:
            raise KeyboardInterrupt
        Path(path).write_text(self.text, encoding="utf-8")


def test_a_snapshot_interrupted_while_saving_leaves_the_previous_one(tmp_path):
    best = tmp_path / "best"
    write_snapshot(best, _Saves("model 1"), _Saves("stats 1"), {"step": 1})
    with pytest.raises(KeyboardInterrupt):
        write_snapshot(best, _Saves("model 2"), _Saves("stats 2", interrupt=True), {"step": 2})
    assert (best / "model.zip").read_text(encoding="utf-8") == "model 1"
    assert json.loads((best / "state.json").read_text(encoding="utf-8")) == {"step": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["best"]
    write_snapshot(best, _Saves("model 3"), _Saves("stats 3"), {"step": 3})
    assert (best / "vecnormalize.pkl").read_text(encoding="utf-8") == "stats 3"
    assert json.loads((best / "state.json").read_text(encoding="utf-8")) == {"step": 3}
    assert [p.name for p in tmp_path.iterdir()] == ["best"]
