"""fgen: frame generation for rendered OpenEXR sequences."""

__version__ = "0.1.0"
