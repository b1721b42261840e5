"""Physical constants typed once, from scipy.constants (the Earth's rate, which scipy lacks, is in
station.model.earth with the rest of the Earth model).

STANDARD_GRAVITY : m/s^2, the conventional g_n = 9.80665 (scipy.constants.g): the unit `g` of
    accelerometer data sheets, and the gravity assumed where the site's is unknown.
"""

import scipy.constants

STANDARD_GRAVITY = scipy.constants.g
