"""FlySky iBus: its codec (`codec`), its line session (`session`), and its output (`output`:
its channels' scale, its registry row, how it is built)."""
