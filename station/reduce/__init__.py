"""Recorded sessions and raw recordings -> averaged readings (Eq. 18, still poses); never imports
drivers."""
