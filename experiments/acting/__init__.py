"""The acting-rule screen on frozen checkpoints: ``python -m experiments acting`` (see ``docs/acting.md``)."""
