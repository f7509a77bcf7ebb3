from sb3_pride.pebble.pebble import PEBBLE

__all__ = ["PEBBLE"]
