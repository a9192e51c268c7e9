"""data/synthetic: the manifest is complete and true, and the samples can be made again bit
for bit from the commands it records."""

import json
import shlex
from pathlib import Path

import pytest

from lfring.cli.main import main
from lfring.synth.samples import SAMPLES, sha256

DATA = Path(__file__).resolve().parent.parent / "data" / "synthetic"
MANIFEST = json.loads((DATA / "manifest.json").read_text())


def test_manifest_lists_every_file_with_its_hash():
    listed = {name for s in MANIFEST["samples"].values() for name in s["files"]}
    present = {str(p.relative_to(DATA)) for p in DATA.rglob("*") if p.is_file() and p.name != "manifest.json"}
    assert listed == present
    for s in MANIFEST["samples"].values():
        for name, digest in s["files"].items():
            assert sha256(DATA / name) == digest, name
    assert set(MANIFEST["samples"]) == set(SAMPLES) == {
        "flat", "target_0.3m", "target_0.5m", "target_1m", "scene", "part_good", "part_defects", "hard"}


def test_sample_set_stays_small():
    total = sum(p.stat().st_size for p in DATA.rglob("*") if p.is_file())
    assert total < 30e6


@pytest.mark.parametrize("name", ["target_1m", "part_defects", "hard"])
def test_regenerating_a_sample_reproduces_it_bit_for_bit(tmp_path, name):
    entry = MANIFEST["samples"][name]
    args = shlex.split(entry["command"])
    assert args[:2] == ["lfring", "synth"] and args[-2:] == ["-o", "data/synthetic"]
    assert main([*args[1:-1], str(tmp_path)]) == 0
    for rel, digest in entry["files"].items():
        assert sha256(tmp_path / rel) == digest, rel
