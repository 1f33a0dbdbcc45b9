"""glmav-observer: MAVLink-connected time-varying velocity observer for the GLMAV.

Koehl, Rafaralahy, Boutayeb, Martinez, "Time-Varying Observers for Launched
Unmanned Aerial Vehicle", 18th IFAC World Congress, 2011 (equation numbers in
comments refer to that paper; see ``../shared/paper/equations.md``).
"""

__version__ = "0.1.0"
