"""Bearer keys: configured as plain keys or ``sha256:<hex>``, compared as hashes.

A key's owner id is the start of its sha256, so meshes and jobs stay with the key that
created them without the key itself ever being stored. Without keys every request is
the one anonymous owner (and the service binds to loopback only).
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Sequence
from dataclasses import dataclass

from service.problems import UnauthorizedError

ANONYMOUS = "anonymous"
_OWNER_HEX = 32


def key_digest(entry: str) -> str:
    """The sha256 hex of a configured key (``sha256:<hex>`` is taken as is)."""
    if entry.startswith("sha256:"):
        return entry.removeprefix("sha256:").lower()
    return hashlib.sha256(entry.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class KeyRing:
    """The configured keys, as digests only."""

    digests: tuple[str, ...]

    @classmethod
    def from_settings(cls, keys: Sequence[str]) -> KeyRing:
        return cls(tuple(key_digest(k) for k in keys))

    @property
    def enabled(self) -> bool:
        return bool(self.digests)

    def owner(self, authorization: str | None) -> str:
        """The owner id for an ``Authorization`` header value; 401 when it is no known key."""
        if not self.enabled:
            return ANONYMOUS
        scheme, _, token = (authorization or "").partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            raise UnauthorizedError("send the header 'Authorization: Bearer <key>'")
        digest = hashlib.sha256(token.strip().encode("utf-8")).hexdigest()
        matched = False
        for known in self.digests:  # compare with every key: no early exit to time
            matched |= hmac.compare_digest(digest, known)
        if not matched:
            raise UnauthorizedError("the bearer key is not one of the configured keys")
        return digest[:_OWNER_HEX]
