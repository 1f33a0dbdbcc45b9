"""Samples -> estimates: the paper's observer, the bank, fault isolation (numpy only, no I/O)."""
