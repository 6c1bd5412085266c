"""Flight logs in MCAP: record, inspect and replay zenoh-robot topics (``zenoh-robot bag``)."""
