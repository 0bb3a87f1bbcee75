"""imls-lightning: Importance Mask Learning (IML) and Synthesis (IMS) for RecNN volume rendering."""

__version__ = "0.1.0"
