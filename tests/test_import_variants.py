"""`station import` of recordings as people publish them (issue 14): one small synthetic recording
written in many layouts - semicolon, tab, a metadata preamble, microseconds, MATLAB v7.3 (laid out
as MATLAB writes it), transposed arrays, an .npz with string metadata, a raw binary packet dump
with 1 % of its packets damaged - must import to the same session data; each refused input names
the problem and the option that fixes it. The real MIMU4444 dumps of ../shared when present."""

import struct
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io

from drivers.profile import SerialImuProfile
from drivers.twins.serial import corrupt_frame
from drivers.wire.binary import encode_frames
from station.cli import main
from station.errors import CalibrationInputError
from station.imports import npz
from station.imports.recordings import import_binary, import_csv, import_npz, import_text
from station.reduce.stillness import detect_still
from station.session import Session
from station.sim.layouts import A_MODEL, gyro_array
from station.sim.profile import RotaryTiming
from station.sim.rotary import simulate_rotary

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
if not REAL.exists():
    REAL = Path("/work/shared/data/real")
MIMU = REAL / "mimu4444-array"

FS = 100.0
K = 400
COLUMNS = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
STREAMS = {"acc": ["ax", "ay", "az"], "gyr": ["gx", "gy", "gz"]}
UNITS = {"acc": "m/s^2", "gyr": "rad/s"}


@pytest.fixture(scope="module")
def recording():
    """(K, 7) rows t ax ay az gx gy gz: 100 Hz from t = 0.5 s, values with 6 decimals (exact in
    the importer's fixed point)."""
    rng = np.random.default_rng(14)
    t = 0.5 + np.arange(K) / FS
    acc = np.round(rng.normal([0, 0, 9.8], 0.05, (K, 3)), 6)
    gyr = np.round(rng.normal(0, 0.01, (K, 3)), 6)
    return np.column_stack([t, acc, gyr])


def write_csv(path, rows, delimiter=",", preamble="", time_column=None, header=COLUMNS):
    lines = [delimiter.join(header)]
    for row in rows:
        first = (f"{time_column(row[0])}" if time_column else f"{row[0]:.2f}")
        lines.append(delimiter.join([first, *(f"{v:.6f}" for v in row[1:])]))
    path.write_text(preamble + "\n".join(lines) + "\n")
    return path


def write_mat73(path, variables: dict) -> Path:
    """A MATLAB v7.3 MAT-file as MATLAB lays it out: HDF5 after a 512-byte user block whose first
    128 bytes are MATLAB's header text, subsystem offset, version 0x0200 and endian "IM"; each
    matrix stored column-major, so the HDF5 dataset holds its transpose, with `MATLAB_class`."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            if isinstance(value, dict):  # a struct
                g = f.create_group(name)
                g.attrs["MATLAB_class"] = np.bytes_("struct")
                for field, v in value.items():
                    g.create_dataset(field, data=np.asarray(v, float).T)
            else:
                d = f.create_dataset(name, data=np.asarray(value, float).T)
                d.attrs["MATLAB_class"] = np.bytes_("double")
    text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Tue Nov 24 12:00:00 2026 " \
           b"HDF5 schema 1.00 ."
    with open(path, "r+b") as f:
        f.write(text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM")
    return path


def arrays_of(path) -> dict:
    with Session.open(path) as s:
        return {name: s.stream(name) for name in s.specs}, s.metadata


def assert_same_session(path, reference):
    """Same streams, channels, units and scales, counts and sequence numbers exactly, times to
    1 ns (a time unit's conversion may differ from the decimal seconds by an ulp)."""
    got, metadata = arrays_of(path)
    want, _ = arrays_of(reference)
    assert got.keys() == want.keys()
    for name, g in got.items():
        w = want[name]
        assert (g.spec.channels, g.spec.units) == (w.spec.channels, w.spec.units)
        assert g.spec.counts_per_unit == w.spec.counts_per_unit
        assert g.spec.rate_hz == pytest.approx(w.spec.rate_hz, rel=1e-9)
        np.testing.assert_array_equal(g.counts, w.counts)
        np.testing.assert_array_equal(g.seq, w.seq)
        np.testing.assert_allclose(g.host_time, w.host_time, rtol=0, atol=1e-9)
    return metadata


@pytest.fixture(scope="module")
def reference(recording, tmp_path_factory):
    """The plain comma CSV, time in seconds, imported: what every variant must give."""
    d = tmp_path_factory.mktemp("reference")
    out = import_csv(d / "ref.h5", write_csv(d / "ref.csv", recording), STREAMS, UNITS,
                     time_column="t")
    data, _ = arrays_of(out)
    np.testing.assert_allclose(data["acc"].to_si(), recording[:, 1:4], atol=1e-12)
    np.testing.assert_allclose(data["gyr"].to_si(), recording[:, 4:], atol=1e-12)
    np.testing.assert_allclose(data["acc"].host_time, recording[:, 0], atol=1e-12)
    return out


PREAMBLE = "Fs,100\nDevice,logger-7\nStart,2026-11-24T10:00:00Z\n\n"


@pytest.mark.parametrize("variant, kwargs, notes", [
    (dict(delimiter=";"), {}, ["delimiter ';' (sniffed)"]),
    (dict(delimiter="\t"), {}, ["delimiter '\\t' (sniffed)"]),
    (dict(delimiter=" "), {}, ["delimiter ' ' (sniffed)"]),
    (dict(preamble=PREAMBLE), {}, ["4 line(s) before the header skipped"]),
    (dict(preamble=PREAMBLE.replace(",", ";"), delimiter=";"), {"skip_rows": 4,
                                                                "delimiter": ";"},
     ["4 line(s) before the header skipped"]),
    (dict(time_column=lambda t: f"{round(t * 1e6)}"), {"time_unit": "us"}, []),
    (dict(time_column=lambda t: f"{round(t * 1e9)}"), {"time_unit": "ns"}, []),
    (dict(time_column=lambda t: f"{t * 1e3:.1f}", delimiter=";", preamble="Fs;100\n"),
     {"time_unit": "ms"}, ["delimiter ';' (sniffed)", "1 line(s) before the header skipped"]),
])
def test_csv_variants_import_to_the_same_session(recording, reference, tmp_path, variant, kwargs,
                                                 notes):
    path = write_csv(tmp_path / "v.csv", recording, **variant)
    out = import_csv(tmp_path / "v.h5", path, STREAMS, UNITS, time_column="t", **kwargs)
    metadata = assert_same_session(out, reference)
    for note in notes:
        assert any(note in n for n in metadata["import"]["notes"]), metadata["import"]["notes"]


def test_csv_refusals_name_the_option_that_fixes_them(recording, tmp_path):
    def refused(path, option, **kw):
        args = {"time_column": "t", **kw}
        with pytest.raises(CalibrationInputError, match=option):
            import_csv(tmp_path / "no.h5", path, STREAMS, UNITS, **args)
        assert not (tmp_path / "no.h5").exists()

    micro = write_csv(tmp_path / "us.csv", recording, time_column=lambda t: f"{round(t * 1e6)}")
    refused(micro, "--time-unit ms, us or ns")  # 1e-4 Hz if seconds
    milli = write_csv(tmp_path / "ms.csv", recording, time_column=lambda t: f"{t * 1e3:.1f}")
    refused(milli, "--time-unit ms, us or ns")  # 0.1 Hz if seconds
    pre = write_csv(tmp_path / "pre.csv", recording, preamble=PREAMBLE)
    refused(pre, "--skip-rows N", skip_rows=2)  # the wrong line taken for the header
    renamed = write_csv(tmp_path / "renamed.csv", recording,
                        header=["t", "acc_x", "ay", "az", "gx", "gy", "gz"])
    refused(renamed, "no line of the first .* holds them all.*--skip-rows N")
    semi = write_csv(tmp_path / "semi.csv", recording, delimiter=";")
    refused(semi, "--delimiter", delimiter=",")  # header not split: no column found
    refused(micro, "Give --time COLUMN with --time-unit", time_column=None, fs=FS,
            time_unit="us")
    words = write_csv(tmp_path / "words.csv", recording).read_text().split("\n")
    words.insert(5, "1.0,2.0,n/a,4,5,6,7")
    (tmp_path / "words.csv").write_text("\n".join(words))
    refused(tmp_path / "words.csv", "not all numbers.*--delimiter and --skip-rows")


def test_a_line_of_units_under_the_header_is_skipped(recording, reference, tmp_path):
    text = write_csv(tmp_path / "plain.csv", recording).read_text().split("\n", 1)
    path = tmp_path / "units.csv"
    path.write_text(PREAMBLE + text[0] + "\ns,m/s^2,m/s^2,m/s^2,rad/s,rad/s,rad/s\n" + text[1])
    out = import_csv(tmp_path / "v.h5", path, STREAMS, UNITS, time_column="t")
    notes = assert_same_session(out, reference)["import"]["notes"]
    assert any("line 6 under the header is not numbers (units?), skipped" in n for n in notes)


def text_tables(recording, d: Path, write) -> dict:
    """The recording as two tables t x y z, one per stream, written by `write(path, table)`."""
    return {"acc": write(d / "acc", recording[:, :4]), "gyr": write(d / "gyr",
                                                               recording[:, [0, 4, 5, 6]])}


@pytest.fixture(scope="module")
def text_reference(recording, tmp_path_factory):
    d = tmp_path_factory.mktemp("text")
    return import_text(d / "ref.h5", text_tables(recording, d, _save_text), UNITS)


ROWS, FLIPPED = "400 samples of 4 columns (time along the rows)", "transposed to 400 samples"


@pytest.mark.parametrize("write, notes", [
    (lambda p, a: _save_text(p, a.T), [FLIPPED]),
    (lambda p, a: write_mat73(p.with_suffix(".mat"), {"rec": a}), ["MATLAB v7.3 file", ROWS]),
    (lambda p, a: write_mat73(p.with_suffix(".mat"), {"rec": a.T}),
     ["MATLAB v7.3 file", FLIPPED]),
    (lambda p, a: _savemat(p, a.T), [FLIPPED]),
    (lambda p, a: _save_text(p, a, delimiter=","), [ROWS]),
])
def test_text_and_matlab_variants_import_to_the_same_session(recording, text_reference, tmp_path,
                                                             write, notes):
    streams = text_tables(recording, tmp_path, write)
    delimiter = "," if any(p.suffix == ".csv" for p in streams.values()) else None
    out = import_text(tmp_path / "v.h5", streams, UNITS, delimiter=delimiter)
    metadata = assert_same_session(out, text_reference)
    for note in notes:
        assert any(note in n for n in metadata["import"]["notes"]), metadata["import"]["notes"]


def _save_text(path, table, delimiter=" "):
    path = path.with_suffix(".csv" if delimiter == "," else ".txt")
    np.savetxt(path, table, fmt="%.6f", delimiter=delimiter)
    return path


def _savemat(path, table):
    path = path.with_suffix(".mat")
    scipy.io.savemat(path, {"rec": table})
    return path


def test_text_time_in_microseconds_needs_its_unit(recording, text_reference, tmp_path):
    table = recording[:, :4].copy()
    table[:, 0] = np.round(table[:, 0] * 1e6)
    np.savetxt(tmp_path / "acc.txt", table, fmt="%.6f")
    gyr = recording[:, [0, 4, 5, 6]].copy()
    gyr[:, 0] = table[:, 0]
    np.savetxt(tmp_path / "gyr.txt", gyr, fmt="%.6f")
    streams = {"acc": tmp_path / "acc.txt", "gyr": tmp_path / "gyr.txt"}
    with pytest.raises(CalibrationInputError, match="--time-unit"):
        import_text(tmp_path / "no.h5", streams, UNITS)
    assert_same_session(import_text(tmp_path / "us.h5", streams, UNITS, time_unit="us"),
                        text_reference)


def test_matlab_refusals_say_what_the_file_is(recording, tmp_path):
    def refused(path, words):
        with pytest.raises(CalibrationInputError, match=words):
            import_text(tmp_path / "no.h5", {"acc": path}, {"acc": "m/s^2"})

    refused(write_mat73(tmp_path / "two.mat", {"a": recording[:, :4], "b": recording[:, :4]}),
            "variables \\['a', 'b'\\].*exactly one")
    refused(write_mat73(tmp_path / "struct.mat", {"s": {"x": recording[:, :4]}}),
            "not a numeric matrix \\(MATLAB class struct\\)")
    broken = tmp_path / "broken.mat"
    broken.write_bytes(write_mat73(tmp_path / "ok.mat", {"a": recording})
                       .read_bytes()[:600])  # header and HDF5 superblock cut short
    refused(broken, "MATLAB v7.3 \\(HDF5\\) file that h5py cannot read")
    junk5 = tmp_path / "junk5.mat"
    junk5.write_bytes(b"MATLAB 5.0 MAT-file" + bytes(range(256)) * 2)
    refused(junk5, "scipy.io cannot read .*not v7.3/HDF5")
    v4 = tmp_path / "future.mat"
    v4.write_bytes(b"MATLAB 9.9 MAT-file, some future layout" + bytes(600))
    refused(v4, "save -v7 or save -v7.3")


def test_npz_string_and_scalar_arrays_are_kept_as_metadata(tmp_path):
    unit = gyro_array(np.random.default_rng(3))
    sim = simulate_rotary(unit, 6, RotaryTiming(static=2, moving=8), a_nominal=A_MODEL)
    plain = tmp_path / "plain.npz"
    npz.write(plain, sim)
    tagged = tmp_path / "tagged.npz"
    np.savez(tagged, **sim.arrays, dataset=np.array("exp_1"), version=np.array(b"v2.1"),
             channels=np.array(["g1", "g2"]), temperature=np.float64(21.5),
             extra=np.zeros((3, 3)))
    want = import_npz(tmp_path / "plain.h5", plain)
    got = import_npz(tmp_path / "tagged.h5", tagged)
    with Session.open(got) as g, Session.open(want) as w:
        np.testing.assert_array_equal(g.stream("imu").counts, w.stream("imu").counts)
        np.testing.assert_array_equal(g.table().angle, w.table().angle)
        kept = g.metadata["import"]["metadata"]
        notes = g.metadata["import"]["notes"]
    assert kept == {"dataset": "exp_1", "version": "v2.1", "channels": ["g1", "g2"],
                    "temperature": 21.5}
    assert any("'extra' (3, 3)" in n and "left out" in n for n in notes)
    objects = tmp_path / "objects.npz"
    np.savez(objects, **sim.arrays, dataset=np.array(["a", 1], dtype=object))
    with pytest.raises(CalibrationInputError, match="type object.*never unpickled.*fixed-width"):
        import_npz(tmp_path / "no.h5", objects)


# ------------------------------------------------------------------------- binary packet dumps

PROFILE = SerialImuProfile.load("mimu4444")
TICK_STEP = 1_024_000  # 16 ms at 64 MHz


def mimu_counts(seq) -> np.ndarray:
    """(k, 48) int16 counts that are a known function of the packet number."""
    seq = np.asarray(seq, np.int64)
    return ((seq[:, None] * 7919 + np.arange(48) * 104729) % 65536 - 32768).astype(np.int64)


def mimu_dump(n: int, corrupt: float, seed: int) -> tuple:
    """(bytes, sent seq, intact mask): a command acknowledgement, n packets whose packet number
    (uint16) and 64 MHz stamp (uint32) both wrap, a fraction `corrupt` damaged by the serial
    twin's corrupt_frame, and a packet cut short at the end."""
    seq = 65_000 + np.arange(n)
    ticks = 2**32 - 50 * TICK_STEP + TICK_STEP * np.arange(n)
    fmt = PROFILE.serial.frame
    data = encode_frames(fmt, seq, ticks, mimu_counts(seq))
    size = len(data) // n
    frames = [data[i * size:(i + 1) * size] for i in range(n)]
    rng = np.random.default_rng(seed)
    hit = rng.random(n) < corrupt
    body = b"".join(corrupt_frame(f, rng) if h else f for f, h in zip(frames, hit, strict=True))
    tail = encode_frames(fmt, [seq[-1] + 1], [ticks[-1] + TICK_STEP],
                         mimu_counts([seq[-1] + 1]))[:83]
    return b"\xa0\x28\x00\xc8" + body + tail, seq, ~hit


def test_encoder_matches_the_documented_packet():
    """One packet built by hand from PROVENANCE's description (struct, builtin sum)."""
    counts = mimu_counts([7])[0]
    body = struct.pack(">BHBI48h", 0xAA, 7, 100, 123456789, *counts)
    hand = body + struct.pack(">H", sum(body) & 0xFFFF)
    assert encode_frames(PROFILE.serial.frame, [7], [123456789], counts[None]) == hand
    assert len(hand) == 106


def test_binary_dump_with_damaged_packets_imports_the_intact_ones(tmp_path):
    clean, seq, _ = mimu_dump(3000, 0.0, seed=1)
    damaged, _, intact = mimu_dump(3000, 0.01, seed=1)
    (tmp_path / "clean.bin").write_bytes(clean)
    (tmp_path / "damaged.bin").write_bytes(damaged)
    assert (~intact).sum() >= 15  # about 1 % of 3000
    ref = import_binary(tmp_path / "clean.h5", tmp_path / "clean.bin", "mimu4444")
    out = import_binary(tmp_path / "damaged.h5", tmp_path / "damaged.bin", "mimu4444")
    with Session.open(ref) as r, Session.open(out) as s:
        want, got, link = r.stream("imu"), s.stream("imu"), s.metadata["import"]["link"]
        assert r.metadata["import"]["link"]["bad_frames"] == 0
        assert r.metadata["profiles"]["imu"]["imu"]["name"] == "mimu4444bt"
    # clean: every packet, packet numbers and stamps unwrapped, time = stamp
    np.testing.assert_array_equal(want.seq, seq)
    np.testing.assert_array_equal(want.counts, mimu_counts(seq))
    expected_t = (2**32 - 50 * TICK_STEP + TICK_STEP * np.arange(3000)) / 64e6
    np.testing.assert_allclose(want.host_time, expected_t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(want.device_time, want.host_time)
    assert want.spec.channels[:7] == ("imu0_ax", "imu0_ay", "imu0_az", "imu0_gx", "imu0_gy",
                                      "imu0_gz", "imu1_ax")
    np.testing.assert_allclose(want.spec.counts_per_unit[:6], [2048 / 9.80665] * 3
                               + [16.4 * 180 / np.pi] * 3)
    # damaged: every intact packet, nothing that was not sent, the rest counted
    assert set(seq[intact]) <= set(got.seq)
    rows = np.searchsorted(want.seq, got.seq)
    np.testing.assert_array_equal(got.counts, want.counts[rows])
    np.testing.assert_array_equal(got.host_time, want.host_time[rows])
    assert link["frames"] == len(got.seq)
    assert link["dropped"] == got.seq[-1] - got.seq[0] + 1 - len(got.seq)  # missing inside
    assert link["bad_frames"] + link["resyncs"] > 0
    assert link["rate_hz"] == pytest.approx(62.5, rel=1e-9)


def test_binary_refusals_name_the_profile(tmp_path):
    dump = tmp_path / "d.bin"
    dump.write_bytes(mimu_dump(50, 0.0, seed=2)[0])
    with pytest.raises(CalibrationInputError, match="--profile"):
        import_binary(tmp_path / "no.h5", dump, "imu12_serial")
    with pytest.raises(CalibrationInputError, match="text lines.*--profile"):
        import_binary(tmp_path / "no.h5", dump, "imu_ascii")
    assert main(["import", "binary", str(tmp_path / "no.h5"), str(dump)]) == 2
    assert not (tmp_path / "no.h5").exists()


def test_cli_prints_how_the_files_were_read(recording, tmp_path, capsys):
    path = write_csv(tmp_path / "v.csv", recording, delimiter=";", preamble="Fs;100\n",
                     time_column=lambda t: f"{round(t * 1e6)}")
    assert main(["import", "csv", str(tmp_path / "v.h5"), str(path), "--time", "t",
                 "--time-unit", "us", "--stream", "acc=ax,ay,az", "--unit", "acc=m/s^2"]) == 0
    out = capsys.readouterr().out
    assert "delimiter ';' (sniffed)" in out and "1 line(s) before the header skipped" in out
    dump = tmp_path / "d.bin"
    dump.write_bytes(mimu_dump(100, 0.0, seed=3)[0])
    assert main(["import", "binary", str(tmp_path / "d.h5"), str(dump), "--profile",
                 "mimu4444", "--json"]) == 0
    assert '"notes": ["d.bin: 100 frames decoded' in capsys.readouterr().out


@pytest.mark.skipif(not MIMU.exists(), reason="needs ../shared/data/real/mimu4444-array")
@pytest.mark.parametrize("name", ["exp_1.bin", "exp_2.bin", "exp_3.bin"])
def test_real_mimu4444_dumps(name, tmp_path):
    """The packets decoded by hand (struct) agree with the import; every packet is intact
    (PROVENANCE: checksums hold, consecutive numbers); 62.5 Hz from the stamps; at rest each IMU
    reads |a| within 0.1 m/s^2 of g (a wrong byte order or scale could not) and its gyros a few
    deg/s (biases; a wrong field alignment would read noise of thousands)."""
    dump = MIMU / name
    raw = dump.read_bytes()
    packets = (len(raw) - 4) // 106
    first = struct.unpack(">BHBI48hH", raw[4:110])
    last = struct.unpack(">BHBI48hH", raw[4 + 106 * (packets - 1):4 + 106 * packets])
    out = import_binary(tmp_path / "e.h5", dump, "mimu4444")
    with Session.open(out) as s:
        data, link = s.stream("imu"), s.metadata["import"]["link"]
    assert link["frames"] == packets and link["bad_frames"] == 0 and link["dropped"] == 0
    np.testing.assert_array_equal(data.counts[0], first[4:52])
    np.testing.assert_array_equal(data.counts[-1], last[4:52])
    assert data.seq[-1] - data.seq[0] == packets - 1
    assert link["rate_hz"] == pytest.approx(62.5, rel=1e-6)
    assert (last[3] - first[3]) % 2**32 == round((data.device_time[-1] - data.device_time[0])
                                                 * 64e6) % 2**32
    x = data.to_si()
    still = detect_still(x, data.spec.rate_hz)
    assert len(still.intervals) >= 20  # the 20 poses of the static phase
    rest = np.concatenate([np.arange(a, b) for a, b in still.intervals])
    per_imu = x[rest].reshape(-1, 8, 6)
    acc = np.linalg.norm(per_imu[:, :, :3], axis=2).mean(axis=0)
    np.testing.assert_allclose(acc, 9.82, atol=0.1)
    assert np.all(np.abs(np.degrees(per_imu[:, :, 3:].mean(axis=0))) < 3)


def test_damaged_dumps_never_crash(tmp_path):
    """Random cuts, garbage and byte flips of a dump: a session of frames that were sent, or a
    refusal naming --profile; never another exception."""
    clean, seq, _ = mimu_dump(60, 0.0, seed=4)
    rng = np.random.default_rng(5)
    for i in range(30):
        data = bytearray(clean[: int(rng.integers(0, len(clean)))])
        for at in rng.integers(0, max(len(data), 1), size=int(rng.integers(0, 20))):
            if at < len(data):
                data[at] ^= int(rng.integers(1, 256))
        data[int(rng.integers(0, len(data) + 1)):0] = rng.bytes(int(rng.integers(0, 300)))
        dump = tmp_path / f"d{i}.bin"
        dump.write_bytes(bytes(data))
        try:
            out = import_binary(tmp_path / f"d{i}.h5", dump, "mimu4444")
        except CalibrationInputError as err:
            assert "--profile" in str(err) or "time stamps" in str(err)
            continue
        with Session.open(out) as s:
            got = s.stream("imu")
        assert set(got.seq) <= set(seq)
        np.testing.assert_array_equal(got.counts, mimu_counts(got.seq))
