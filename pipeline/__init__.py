"""Pipeline: scene loading and validation, stage orchestration, Rerun recording, CLI."""
