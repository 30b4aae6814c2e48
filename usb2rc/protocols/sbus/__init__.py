"""The sbus package."""
