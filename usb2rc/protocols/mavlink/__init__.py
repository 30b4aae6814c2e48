"""MAVLink: its decoder and field values (`codec`, through pymavlink), its channels, engine
and line session (`session`), its actions (`actions`), and its output (`output`: its registry
row, its own config keys, how it is built)."""
