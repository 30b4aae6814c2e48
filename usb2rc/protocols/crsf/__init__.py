"""CRSF: its codec (`codec`), its line session and the module it follows (`session`), what
`check` warns of its far end (`checks`), and its output (`output`: its registry row, its own
config keys, how it is built)."""
