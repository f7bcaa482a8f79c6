"""Physical constants of the truth model (docs/design.md, "The default mission"). SI units."""

MU_EARTH: float = 3.986004415e14
"""Earth's gravitational parameter, m^3/s^2."""

R_EARTH: float = 6378136.6
"""Earth's equatorial radius, m (the J2 reference radius)."""

J2_EARTH: float = 1.08262668e-3
"""Earth's second zonal harmonic, dimensionless."""
