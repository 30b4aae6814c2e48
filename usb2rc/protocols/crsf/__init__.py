"""The crsf package."""
