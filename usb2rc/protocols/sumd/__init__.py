"""Graupner HoTT SUMD: its codec (`codec`), its channels (`channels`), its line session
(`session`), what `check` says of receivers (`receivers`), and its output (`output`: its
registry row, its own config key, how it is built)."""
