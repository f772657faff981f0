"""Stage classes (thin wrappers around fgcli.ops) and the registry (base.REGISTRY)."""
