"""The c2_16b package."""
