"""Pipeline stages. Each stage is a plain function from typed inputs to a typed output dataclass;
stages never read YAML, parse CLI arguments or open the recording (that is `pipeline`'s job)."""
