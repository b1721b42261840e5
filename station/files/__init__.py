"""Files the station owns: session files (session/), calibration files (calfile), combined
calibrations (combined), the thermal campaign's manifest (campaign), numeric tables read from text
(tables), the simulator's data and truth files (npz.py), provenance and the one numpy -> JSON
adapter (jsonable.py). Foreign recordings come in through station/imports/, calibrations go out to
other tools through station/exports/."""
