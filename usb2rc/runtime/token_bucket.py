"""TokenBucket: a rate with a burst, for whatever must not run faster than it (bytes a far
end may send, output states a device is shown). Sans-IO: the caller passes the time."""

from __future__ import annotations

EPSILON = 1e-9  # float sums: a bucket this close to a whole token holds it


class TokenBucket:
    """`burst` tokens at first, refilled at `rate_per_s`, never above `burst`."""

    def __init__(self, rate_per_s: float, burst: float, now: float) -> None:
        self.rate_per_s = rate_per_s
        self.burst = float(burst)
        self._tokens = float(burst)
        self._at = now  # the bucket's clock

    def level(self, now: float) -> float:
        """The tokens there at `now`."""
        self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate_per_s)
        self._at = now
        return self._tokens

    def wait_s(self, now: float, amount: float = 1.0) -> float:
        """0 when `amount` tokens are there, else how long until they are."""
        missing = amount - self.level(now)
        return 0.0 if missing <= EPSILON else missing / self.rate_per_s

    def take(self, now: float, amount: float = 1.0) -> None:
        self._tokens = self.level(now) - amount
