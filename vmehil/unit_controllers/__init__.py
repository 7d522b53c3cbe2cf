"""MELMALEC's unit controllers in parallel: the coordinator, the lockstep hub (docs/melmalec.md)."""
