"""edgedsm: dynamic speckle activity maps from the lab to the factory floor.

Reference: Levchenko et al., "Noise analysis in outdoor dynamic speckle measurement"
(Optica, 2022); equations are cited as "Eq. n" of that paper throughout.
"""

__version__ = "0.1.0"
