"""Foreign recordings into session files (`station import`): text tables, CSV, the simulator's
npz arrays and raw serial dumps (recordings), Kalibr/EuRoC CSV (kalibr), flight-controller logs
(flightlog: PX4 ULog in ulog, ArduPilot DataFlash in dataflash). Every file is untrusted input."""
