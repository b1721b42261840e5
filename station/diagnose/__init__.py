"""`station diagnose`: where a rotary session and its digital twin disagree, which named effect
explains it, and the calibration once that effect is in the model (docs/diagnose.md).

Modules: `data` (the session), `twin` (replay with fitted parameters), `linear` (least squares on
binned residuals), `effects/<name>` (one model extension per named effect), `rails` (output
pile-up), `model` (joint fit), `gap` (the statistics), `select` (the evidence loop), `report`;
the samples' own law: `outliers` (spikes), `quantisation` (the step and what a mean keeps of it).
"""

from station.diagnose.select import Diagnosis, diagnose

__all__ = ["Diagnosis", "diagnose"]
