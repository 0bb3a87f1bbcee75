"""Hydra sweeper ``hydra/sweeper=orp``: the ORP search of the IML mean value (see ``docs/ORP.md``).

``hydra_plugins`` is a namespace package (no ``__init__.py`` at its top): Hydra imports every
module under it to discover plugins, so this package imports nothing heavy (no torch).
"""

__version__ = "0.1.0"
