"""Issue 31: raw counts imported without their scale (`--unit acc=counts:m/s^2`) are labelled
counts everywhere a value of them is shown: the calibration file (readings, bias, noise), `station
solve`'s and `station noise`'s output, the Allan plot and the report's figures and tables, `station
apply`'s check; the export formats, which need SI readings, refuse them naming the fix (the scale,
`counts:m/s^2@SCALE`). The same recording imported with its scale is in SI throughout (the
control: the checks below tell the two apart).

The recording: the hand-held poses and turns of tests/test_gyro_carry.py (100 Hz), as a 16-bit
IMU's counts would hold them (mid-scale offset, 415 counts per m/s^2, 3000 per rad/s)."""

import json

import matplotlib.text
import numpy as np
import pytest
from test_gyro_carry import G, hand_recording, true_sensitivity
from test_import_solve import station_with_errors as station

from station.calfiles.calfile import load
from station.report import html

ACC_SCALE, GYRO_SCALE = 415.0, 3000.0
SI = ("m/s^2", "rad/s")


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    """Text tables `t x y z` of the accelerometer and gyro counts."""
    gyro, acc, _ = hand_recording(11, true_sensitivity(7))
    folder = tmp_path_factory.mktemp("counts")
    t = 0.01 * np.arange(len(acc))
    for name, values, scale in (("acc", acc, ACC_SCALE), ("gyro", gyro, GYRO_SCALE)):
        counts = np.rint(values * scale + 32768)
        np.savetxt(folder / f"{name}.txt", np.column_stack([t, counts]), fmt="%.2f %d %d %d")
    return folder


@pytest.fixture
def figures(monkeypatch):
    """The texts of every figure the station renders to PNG (titles, axis labels, notes)."""
    texts = []
    png = html.png

    def spy(fig):
        texts.extend(t.get_text() for t in fig.findobj(matplotlib.text.Text))
        return png(fig)

    monkeypatch.setattr(html, "png", spy)
    return texts


def imported(capsys, tables, out, scaled: bool):
    units = [f"acc=counts:m/s^2@{ACC_SCALE:g}", f"gyro=counts:rad/s@{GYRO_SCALE:g}"] if scaled \
        else ["acc=counts:m/s^2", "gyro=counts:rad/s"]
    code, _, err = station(capsys, "import", "text", out, "--stream", f"acc={tables / 'acc.txt'}",
                           "--stream", f"gyro={tables / 'gyro.txt'}", "--unit", units[0],
                           "--unit", units[1])
    assert code == 0, err
    return out


def si_labels(text: str) -> list:
    """The SI units named in a text (outside the stimulus magnitude's line)."""
    lines = [line for line in text.splitlines() if not line.startswith("magnitude ")]
    return [u for u in SI if any(u in line for line in lines)]


@pytest.mark.parametrize("scaled", [False, True], ids=["counts", "scaled"])
def test_counts_are_labelled_counts_everywhere(tables, tmp_path, capsys, figures, scaled):
    h5 = imported(capsys, tables, tmp_path / "imu.h5", scaled)
    expect = ("m/s^2", "rad/s") if scaled else ("counts", "counts")

    code, out, err = station(capsys, "solve", h5, "--store", "--magnitude", G)
    assert code == 0, err
    assert f"(bias in {expect[0]})" in out
    assert si_labels(out) == ([] if not scaled else ["m/s^2"])
    cal = load(tmp_path / "imu.cal.json")
    doc = json.loads((tmp_path / "imu.cal.json").read_text())
    assert cal.units == (expect[0],) * 3 and cal.quantity == "m/s^2"
    assert doc["units"]["stimulus"] == "m/s^2" and doc["units"]["readings"] == [expect[0]] * 3
    assert doc["noise"]["units"]["white"] == f"{expect[0]} sqrt(s)"

    code, out, err = station(capsys, "solve", h5, "--stream", "gyro", "--magnitude", G, "--out",
                             tmp_path / "gyro.cal.json")
    assert code == 0, err
    gyro = load(tmp_path / "gyro.cal.json")
    assert gyro.units == (expect[1],) * 3 and gyro.quantity == "rad/s"
    assert gyro.noise is not None and f"{expect[1]} sqrt(s)" in out

    for stream, unit in zip(("acc", "gyro"), expect, strict=True):
        del figures[:]
        code, out, _ = station(capsys, "noise", h5, "--stream", stream, "--json", "--plot",
                               tmp_path / f"{stream}.png")
        assert code == 0
        said = {channel[key]["unit"] for channel in json.loads(out)["channels"]
                for key in ("white", "bias_instability", "random_walk")}
        assert said == {f"{unit} sqrt(s)", unit, f"{unit} / sqrt(s)"}
        assert {channel["unit"] for channel in json.loads(out)["channels"]} == {unit}
        assert f"Allan deviation ({unit})" in figures
        assert all(unit in t for t in figures if "sqrt(s)" in t)
        code, out, _ = station(capsys, "noise", h5, "--stream", stream)
        assert si_labels(out) == ([] if not scaled else [unit])

    del figures[:]
    code, out, err = station(capsys, "report", h5, "--out", tmp_path / "r.html")
    assert code == 0, err
    assert f"bias ({expect[0]})" in figures
    assert si_labels("\n".join(figures)) == ([] if not scaled else list(SI))
    page = (tmp_path / "r.html").read_text()
    assert f"{expect[0]} sqrt(s)" in page and f"{expect[1]} sqrt(s)" in page
    if not scaled:
        assert "m/s^2 sqrt(s)" not in page and "rad/s sqrt(s)" not in page

    # `station apply` takes the session's readings in the calibration's unit
    code, out, err = station(capsys, "apply", tmp_path / "imu.cal.json", h5, "--stream", "acc",
                             "--out", tmp_path / "v.csv")
    assert code == 0, err
    assert (tmp_path / "v.csv").read_text().splitlines()[0] == \
        "time [s],v_x [m/s^2],v_y [m/s^2],v_z [m/s^2]"  # v is in the stimulus' unit either way


def test_exports_refuse_counts_naming_the_scale(tables, tmp_path, capsys):
    h5 = imported(capsys, tables, tmp_path / "imu.h5", scaled=False)
    assert station(capsys, "solve", h5, "--magnitude", G)[0] == 0
    assert station(capsys, "solve", h5, "--stream", "gyro", "--magnitude", G, "--out",
                   tmp_path / "gyro.cal.json")[0] == 0
    acc = tmp_path / "imu.cal.json"
    for options in (["--to", "kalibr", "--gyro", tmp_path / "gyro.cal.json"],
                    ["--to", "ardupilot"], ["--to", "px4"], ["--to", "ros"],
                    ["--to", "imucal", "--gyro", tmp_path / "gyro.cal.json"],
                    ["--to", "c-header"]):
        code, _, err = station(capsys, "export", acc, *options)
        assert code == 2, options
        assert "raw counts whose scale was not known" in err
        assert "--unit NAME=counts:m/s^2@SCALE" in err
    code, _, err = station(capsys, "export", tmp_path / "gyro.cal.json", "--to", "ros")
    assert code == 2 and "counts:rad/s@SCALE" in err
    assert not list(tmp_path.glob("*.yaml")) + list(tmp_path.glob("*.h"))


def test_a_counts_calibration_file_round_trips_and_its_stimulus_is_checked():
    from test_calfile import edited, make

    from station.calfiles.calfile import loads
    from station.errors import CalibrationFileError

    cal = make(units=("counts",) * 4, stimulus="rad/s")
    doc = cal.to_document()
    assert doc["units"]["stimulus"] == "rad/s" and doc["units"]["sensitivity"] == \
        "counts per rad/s"
    back = loads(cal.dumps())
    assert back.units == ("counts",) * 4 and back.quantity == "rad/s"
    assert loads(make().dumps()).stimulus is None  # SI readings: the stimulus is theirs
    for stimulus in ("counts", None, "furlong"):
        with pytest.raises(CalibrationFileError, match="units.stimulus"):
            loads(edited(cal, lambda d, s=stimulus: d["units"].update(stimulus=s), True))
    with pytest.raises(CalibrationFileError, match="must be one SI unit"):
        loads(edited(cal, lambda d: d["units"].update(readings=["counts", "rad/s"] * 2), True))
