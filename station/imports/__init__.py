"""Foreign recordings into session files (`station import`): text tables, CSV, the simulator's
npz arrays and raw serial dumps (recordings), Kalibr/EuRoC CSV (kalibr), flight-controller logs
(flightlog: PX4 ULog in ulog, ArduPilot DataFlash in dataflash). The readers under them: numeric
tables from text, CSV and MATLAB files (tables), npz arrays with their sizes checked from the
headers, and the simulator's data and truth files written in the same format (npz). Every file is
untrusted input."""
