"""metalens: design and analysis of learned split-spectrum metalenses.

Every length in the package is in SI metres; wavelengths too.
"""

__version__ = "0.1.0"
