"""`station simulate`: the data file holds the import format, the truth lives beside it."""

import json

import numpy as np
import pytest

from station import cli
from station.imports import npz
from station.reduce.eq18 import reduce_arrays

ROTARY_KEYS = {
    "y",
    "lsb",
    "fs",
    "t0",
    "rate_cmd",
    "c_cmd",
    "angle",
    "a_nominal",
    "seg_static",
    "seg_spinup",
    "seg_settle",
    "seg_rotating",
    "seg_spindown",
}


def station(*argv):
    """Run `station simulate ...`; its exit code."""
    return cli.main(["simulate", *argv])


def test_rotary_file_has_the_import_keys_and_no_truth(tmp_path):
    out = tmp_path / "x.npz"
    assert (
        station("--protocol", "rotary", "--positions", "6", "--seed", "4", "--out", str(out)) == 0
    )
    arrays = npz.read(out)
    assert set(arrays) == ROTARY_KEYS
    n, k, m = arrays["y"].shape
    assert (n, m) == (6, 12) and arrays["y"].dtype == np.int32 and arrays["rate_cmd"].shape == (k,)
    assert arrays["a_nominal"].shape == (3, 12) and arrays["t0"].shape == (n,)
    truth = json.loads((tmp_path / "x.truth.json").read_text())
    assert truth["protocol"] == "rotary" and np.shape(truth["a"]) == (3, 12)
    red = reduce_arrays(arrays)  # the file reduces to a^T v within the noise
    expected = np.array(truth["a"]).T @ np.array(truth["v"])
    assert np.abs(red.M - expected).max() < 6 * red.sigma.max()


def test_same_seed_same_file_other_seed_other_data(tmp_path):
    for name, seed in (("a", "1"), ("b", "1"), ("c", "2")):
        station(
            "--positions",
            "3",
            "--seed",
            seed,
            "--effect",
            "latency=delay=0.001",
            "--out",
            str(tmp_path / f"{name}.npz"),
        )
    ya, yb, yc = (npz.read(tmp_path / f"{x}.npz")["y"] for x in "abc")
    assert np.array_equal(ya, yb) and not np.array_equal(ya, yc)
    assert npz.read_truth(tmp_path / "a.npz")["effects"] == {"latency": {"delay": 0.001}}


@pytest.mark.parametrize(
    "protocol, keys",
    [
        ("iron", {"y", "lsb", "fs", "t0", "c_cmd", "mounting", "seg_still", "a_nominal"}),
        ("static", {"y", "lsb", "fs", "t0", "c_cmd", "a_nominal"}),
    ],
)
def test_iron_and_static_files(tmp_path, protocol, keys):
    out = tmp_path / "s.npz"
    assert station("--protocol", protocol, "--out", str(out)) == 0
    arrays = npz.read(out)
    assert set(arrays) == keys and arrays["y"].shape[2] == 3


def test_bad_requests_fail_with_a_message_and_write_nothing(tmp_path, capsys):
    assert station("--effect", "wobble", "--out", str(tmp_path / "x.npz")) == 2
    assert "unknown effect" in capsys.readouterr().err
    assert station("--out", str(tmp_path / "x.h5")) == 2
    assert "must end with .npz" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
