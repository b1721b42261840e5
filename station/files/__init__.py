"""Files the station reads and writes: session files, calibration files, imports and exports, the
simulator's data and truth files (npz.py), and the one numpy -> JSON adapter (jsonable.py)."""
