"""SERaero C2-16B: its codec (`codec`), its line's engine (`engine`) and session (`session`),
the data statuses (`data_status`), a receiver's model (`receiver`), and its output (`output`:
its registry row, its own config keys, how it is built)."""
