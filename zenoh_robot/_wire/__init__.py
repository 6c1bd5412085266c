"""The wire, private to the library: the sample envelope, redundancy (history carried in each
sample, deduplication) and repeats (delayed copies). See docs/architecture.md.
"""
