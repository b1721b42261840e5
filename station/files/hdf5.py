"""HDF5 datasets the station reads from untrusted files: their values stored in the file itself,
passed only through filters h5py decodes without a plugin. A session file (station.session) and a
MATLAB v7.3 table (station.imports.tables) are both read through `stored_plainly`."""

import h5py

ALLOWED_FILTERS = frozenset({h5py.h5z.FILTER_DEFLATE, h5py.h5z.FILTER_SHUFFLE,
                             h5py.h5z.FILTER_FLETCHER32})
"""The filters a dataset read by the station may use: the session writer's chunk checksum
(fletcher32) and the compression MATLAB v7.3 writes (deflate, shuffle)."""


def stored_plainly(dataset: h5py.Dataset) -> bool:
    """True when `dataset`'s values live in this file (no external storage, not virtual) and
    pass only through `ALLOWED_FILTERS`."""
    plist = dataset.id.get_create_plist()
    filters = {plist.get_filter(i)[0] for i in range(plist.get_nfilters())}
    return not (dataset.external or dataset.is_virtual) and filters <= ALLOWED_FILTERS
