"""Services over Zenoh queryables (filled in by the services/parameters work)."""
from __future__ import annotations


class ServicesMixin:
    def _init_services(self) -> None:
        pass
