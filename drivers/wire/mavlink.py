"""MAVLink IMU messages <-> the station's counts: which message, which fields, which units.

The frames themselves are parsed and built by pymavlink's generated `common` dialect (MAVLink 2,
which also reads MAVLink 1 frames); this module only says what the IMU messages of the MAVLink
common message set (common.xml, https://mavlink.io/en/messages/common.html) mean:

| family        | messages; the instance is                    | acc   | gyro   | mag    |
| ------------- | -------------------------------------------- | ----- | ------ | ------ |
| `HIGHRES_IMU` | #105; its `id` field                         | m/s^2 | rad/s  | gauss  |
| `SCALED_IMU`  | SCALED_IMU #26, SCALED_IMU2 #116, _IMU3 #129 | mG    | mrad/s | mgauss |
| `RAW_IMU`     | #27; its `id` field                          | raw   | raw    | raw    |

HIGHRES_IMU sends float32 values in SI (gauss for the magnetometer): a count is the value times the
profile's counts per SI unit, rounded. SCALED_IMU sends int16 in milli-units: the integer *is* the
count, with fixed counts per SI unit (1000 / 9.80665 per m/s^2: MAVLink's g is standard gravity,
9.80665 m/s^2; 1000 per rad/s; 1e7 per T, 1 gauss = 1e-4 T). RAW_IMU sends the sensor's raw int16:
the integer is the count, its scale unknown to MAVLink (the profile gives it).
"""

from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

STANDARD_GRAVITY = 9.80665
"""m/s^2: the g of MAVLink's mG (standard gravity, 3rd CGPM 1901)."""

QUANTITY = {axis + kind: unit for kind, unit in (("acc", "m/s^2"), ("gyro", "rad/s"),
                                                   ("mag", "T")) for axis in "xyz"}
"""Message field -> SI unit of the channel it feeds (the fields every IMU message shares)."""

SI_PER_WIRE = {
    "HIGHRES_IMU": {"m/s^2": 1.0, "rad/s": 1.0, "T": 1e-4},
    "SCALED_IMU": {"m/s^2": STANDARD_GRAVITY / 1000, "rad/s": 1e-3, "T": 1e-7},
}
"""SI units per unit of a message's field (RAW_IMU: unknown, the profile's scale)."""

DEFAULT_SCALE = {"m/s^2": 1e5, "rad/s": 1e6, "T": 1e9}
"""HIGHRES_IMU's default counts per SI unit: finer than float32's resolution at the sensors'
ranges (1e-5 m/s^2, 1e-6 rad/s, 1 nT)."""

INT16 = (-32768, 32767)


@dataclass(frozen=True)
class ImuMessage:
    """The IMU message one profile reads: `family`, `instance` and the field of each channel."""

    family: str
    instance: int
    fields: tuple

    @property
    def name(self) -> str:
        """The MAVLink message name (SCALED_IMU2 for instance 1 of SCALED_IMU)."""
        if self.family == "SCALED_IMU" and self.instance:
            return f"SCALED_IMU{self.instance + 1}"
        return self.family

    @property
    def msg_id(self) -> int:
        return getattr(mavlink, f"MAVLINK_MSG_ID_{self.name}")

    @property
    def is_float(self) -> bool:
        return self.family == "HIGHRES_IMU"

    def fixed_scale(self, unit: str) -> float | None:
        """Counts per SI unit the message fixes for a channel of `unit` (None: the profile's)."""
        if self.family != "SCALED_IMU":
            return None
        return 1.0 / SI_PER_WIRE["SCALED_IMU"][unit]

    def instance_of(self, msg) -> int:
        """The instance a decoded message of this family belongs to."""
        if self.family == "SCALED_IMU":
            name = msg.get_type()
            return int(name[-1]) - 1 if name[-1].isdigit() else 0
        return int(getattr(msg, "id", 0) or 0)

    def is_family(self, msg) -> bool:
        """Is `msg` a message of this family (any instance)?"""
        name = msg.get_type()
        return name == self.family or (self.family == "SCALED_IMU" and name in
                                       ("SCALED_IMU2", "SCALED_IMU3"))

    def time_of(self, msg) -> float:
        """The message's time stamp in seconds (time_usec, or time_boot_ms)."""
        if self.family == "SCALED_IMU":
            return msg.time_boot_ms * 1e-3
        return msg.time_usec * 1e-6

    def counts(self, msg, scale: np.ndarray) -> np.ndarray | None:
        """(m,) int64 counts of one decoded message (`scale`: counts per SI unit per channel);
        None when a float field is not finite or beyond the counts' range (an invalid
        sample)."""
        values = np.array([getattr(msg, f) for f in self.fields], float)
        if not self.is_float:
            return values.astype(np.int64)
        si = values * [SI_PER_WIRE["HIGHRES_IMU"][QUANTITY[f]] for f in self.fields]
        counts = np.round(si * scale)
        if not np.all(np.abs(counts) < 2.0**62):  # NaN fails too
            return None
        return counts.astype(np.int64)

    def wire_values(self, counts, scale: np.ndarray) -> np.ndarray:
        """(k, m) field values of messages carrying `counts` (k, m): the inverse of `counts`
        (int16 fields clipped to their range, like a saturating sensor)."""
        counts = np.asarray(counts)
        if not self.is_float:
            return np.clip(counts, *INT16).astype(np.int64)
        si = counts / np.asarray(scale, float)
        return si / [SI_PER_WIRE["HIGHRES_IMU"][QUANTITY[f]] for f in self.fields]

    def encode(self, mav, time_s: float, values) -> object:
        """The pymavlink message sampled at `time_s` with the channels' field `values`; the other
        fields 0 (HIGHRES_IMU: fields_updated marks acc, gyro and mag, bits 0-8)."""
        fields = dict.fromkeys(QUANTITY, 0)
        fields.update(zip(self.fields, (v.item() for v in np.asarray(values)), strict=True))
        if self.family == "SCALED_IMU":
            return getattr(mav, f"{self.name.lower()}_encode")(
                int(round(time_s * 1e3)) & 0xFFFFFFFF, *(fields[f] for f in QUANTITY))
        stamp = int(round(time_s * 1e6))
        if self.family == "HIGHRES_IMU":
            return mav.highres_imu_encode(stamp, *(float(fields[f]) for f in QUANTITY),
                                          0.0, 0.0, 0.0, 0.0, 0x1FF, self.instance)
        return mav.raw_imu_encode(stamp, *(fields[f] for f in QUANTITY), self.instance)
