"""glmav-observer: MAVLink-connected time-varying velocity observer for the GLMAV.

Koehl, Rafaralahy, Boutayeb, Martinez, "Time-Varying Observers for Launched
Unmanned Aerial Vehicle", 18th IFAC World Congress, 2011 (equation numbers in
comments refer to that paper; docs/model.md writes the model out).
"""

from glmav_observer import _compiled
from glmav_observer._version import __version__

# before any compiled module is imported: an edited source runs, not its stale copy
_compiled.install()

__all__ = ["__version__"]
