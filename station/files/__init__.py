"""What every file the station writes or reads shares: where it came from (provenance: software
version, creation time), JSON values (jsonable: the one numpy -> JSON adapter) and the HDF5
datasets it will read (hdf5: stored in the file, known filters). The files themselves have rooms of
their own: session files and campaigns (station/session/), calibration files (station/calfiles/),
foreign recordings coming in (station/imports/), calibrations going out (station/exports/)."""
