"""The configuration: YAML nodes to checked, typed config records (file:line problems)."""
