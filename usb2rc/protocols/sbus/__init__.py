"""Futaba SBUS: its codec (`codec`), its line session (`session`), and its output (`output`:
its registry row, how it is built)."""
