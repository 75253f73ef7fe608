"""The trained starting counts of the entropy models: a fixed part of the format, complete and checked."""

import hashlib
import json
import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from facedeform.codec.model.face_model import load_base_face
from facedeform.common.parameters import LAYOUTS
from facedeform.protocol import priors
from facedeform.protocol.entropy import GroupState
from facedeform.protocol.quantise import QUALITIES
from facedeform.protocol.stream import Frame, Header, StreamDecoder, StreamEncoder, steps_for
from facedeform.receiver import cli as receiver_cli
from tests.support import ROOT

NAMES = ("theta", "v2x", "v2y", "v2z", "v3x", "v3y", "v3z", "v8x", "v8y", "v8z", "v9x", "v9y", "v9z")


def model_names() -> set[str]:
    """Every model a group makes, by the name the table uses."""
    made = []
    GroupState(12, True, lambda key: made.append(priors.key_name(key)) or priors.AdaptiveBit())
    return set(made)


def test_every_level_has_a_table_of_small_counts_for_models_that_exist():
    tables = priors.tables()
    assert sorted(tables) == [str(q) for q in QUALITIES]
    names = model_names()
    for table in tables.values():
        assert table and set(table) <= names
        for n0, n1 in table.values():
            assert isinstance(n0, int) and isinstance(n1, int) and 0 <= n0 and 0 <= n1 and 0 < n0 + n1 <= 16


@pytest.mark.parametrize("damage, message", [
    (lambda data: data.replace(b"[", b"[1", 1), "is not the entropy table of this stream format"),
    (None, "cannot read"),
])
def test_a_table_that_is_not_this_versions_is_refused_in_one_line(tmp_path, monkeypatch, capsys, damage, message):
    """fd-recv on a good stream, with the installed table altered or gone: one line, exit 1."""
    stream = tmp_path / "s.fd"
    h = Header(25.0, NAMES, steps_for(NAMES), load_base_face().content_id)  # the face fd-recv holds
    enc = StreamEncoder(h, 2)
    stream.write_bytes(enc.header() + b"".join(enc.frame(np.zeros(len(NAMES)), True) for _ in range(3)) + enc.end())
    altered = tmp_path / "priors.json"
    if damage is not None:
        altered.write_bytes(damage(priors.PATH.read_bytes()))
    args = [str(stream), "-o", str(tmp_path / "out.y4m"), "-q"]
    monkeypatch.setattr(priors, "PATH", altered)
    priors.tables.cache_clear()
    try:
        code = receiver_cli.main(args)
        err = capsys.readouterr().err
    finally:
        monkeypatch.undo()
        priors.tables.cache_clear()
    assert code == 1 and message in err and err.count("\n") == 1 and "Traceback" not in err
    assert receiver_cli.main(args) == 0  # the same stream with the installed table


def test_trained_models_start_from_the_levels_counts_and_custom_steps_take_the_default_levels():
    level = Header(25.0, NAMES, steps_for(NAMES, 2), "00" * 32, quality=2)
    custom = replace(level, steps=steps_for(NAMES, 2) * 1.3, quality=0)
    name, (n0, n1) = next(iter(priors.tables()["2"].items()))
    key = tuple(int(p) if p.isdigit() else p for p in name.split("."))
    model = priors.models_for(level)(key)
    assert (model.n0, model.n1) == (n0, n1)
    three = priors.tables()["3"].get(name, [0, 0])
    assert [priors.models_for(custom)(key).n0, priors.models_for(custom)(key).n1] == three
    params = np.cumsum(np.random.default_rng(3).normal(0, 2, (40, len(NAMES))), axis=0) * custom.steps
    enc = StreamEncoder(custom, 2)
    data = enc.header() + b"".join(enc.frame(p, True) for p in params) + enc.end()
    dec = StreamDecoder()
    got = np.array([e.params for e in dec.feed(data) + dec.close() if isinstance(e, Frame)])
    assert len(got) == len(params) and not dec.stats.damaged and dec.header == custom
    assert np.all(np.abs(got - params) <= custom.steps * (1 + 1e-9))  # the default dead zone: one step



def test_the_training_script_writes_a_table_of_the_same_form(tmp_path):
    """benchmarks/train_priors.py on one synthetic talking dump: every level, known models, small counts."""
    names = LAYOUTS["paper"]
    rng = np.random.default_rng(5)
    mouth = np.sin(np.arange(100) / 3.0)[:, None] * rng.normal(0, 1, len(names))
    params = (mouth * 8 + np.cumsum(rng.normal(0, 0.7, (100, len(names))), axis=0)) * steps_for(names)
    dump = tmp_path / "clip.paper.npz"
    np.savez(dump, names=np.array(names), fps=25.0, params=params, found=np.ones(100, bool))
    out = tmp_path / "priors.json"
    run = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "train_priors.py"), str(dump), "-o", str(out)],
                         capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert run.returncode == 0, run.stderr
    tables = json.loads(out.read_bytes())
    assert sorted(tables) == [str(q) for q in QUALITIES] and hashlib.sha256(out.read_bytes()).hexdigest() in run.stdout
    for table in tables.values():
        assert table and set(table) <= model_names()
        assert all(0 < n0 + n1 <= 16 for n0, n1 in table.values())
