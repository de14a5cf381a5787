"""Imitation learning: demonstration collection with the online NeRF, datasets, behaviour cloning, DAgger."""
