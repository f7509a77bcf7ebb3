from sb3_pride.pride.pride import PRIDE

__all__ = ["PRIDE"]
