"""Garment stage: cloth meshes (generators, sewing patterns, imported meshes) as simulation input."""
