"""The wire, private to the library: the envelope codec (the bytes of the default wire format, public
as ``zenoh_robot.wire.ENVELOPE``), redundancy (history carried in each sample, deduplication) and
repeats (delayed copies). See docs/architecture.md.
"""
