"""Rig stage: characters from glTF, BVH or the built-in generator; skinning; region split."""
