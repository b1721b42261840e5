"""Files the station reads and writes: session files, calibration files, imports and exports."""
