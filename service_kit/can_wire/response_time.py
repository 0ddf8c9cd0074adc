"""Worst-case response times of CAN messages, written from Davis, Burns,
Bril and Lukkien (2007), "Controller Area Network (CAN) schedulability
analysis: refuted, revisited and revised", Real-Time Systems 35:239-272,
section 4 (the revised analysis): the bound the arbitration model
(:mod:`service_kit.can_wire.arbitration`) is tested against, and the
"analysis" column of the restbus report (:mod:`service_kit.can_wire.restbus`).
Integer nanoseconds throughout; jitter J defaults to 0.

- ``B_m``: the longest lower-priority ``C_k`` (0 for the lowest);
- busy period ``t_m = B_m + sum_{k in hep(m)} ceil((t_m + J_k) / T_k) C_k``,
  ``Q_m = ceil((t_m + J_m) / T_m)`` instances in it;
- for ``q < Q_m``: ``w_m(q) = B_m + q C_m + sum_{k in hp(m)} ceil((w_m(q) + J_k + tau_bit) / T_k) C_k``,
  ``R_m(q) = J_m + w_m(q) - q T_m + C_m``; ``R_m = max_q R_m(q)``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Message:
    priority: int
    """Lower is higher priority (the identifier)."""
    c_ns: int
    """Transmission time C_m, intermission included."""
    t_ns: int
    """Period T_m."""
    j_ns: int = 0


def _ceil(a: int, b: int) -> int:
    return -(-a // b)


def response_times(messages: list[Message], tau_bit_ns: int) -> dict[int, int]:
    """R_m for each message (by priority); ValueError where the busy period does not converge."""
    out: dict[int, int] = {}
    for m in messages:
        hp = [k for k in messages if k.priority < m.priority]
        hep = hp + [m]
        lp = [k for k in messages if k.priority > m.priority]
        if sum(k.c_ns / k.t_ns for k in hep) >= 1.0:
            raise ValueError(f"utilisation of hep({m.priority}) >= 1")
        b = max((k.c_ns for k in lp), default=0)
        t = m.c_ns
        while True:
            new = b + sum(_ceil(t + k.j_ns, k.t_ns) * k.c_ns for k in hep)
            if new == t:
                break
            t = new
        q_m = _ceil(t + m.j_ns, m.t_ns)
        worst = 0
        for q in range(q_m):
            w = b + q * m.c_ns
            while True:
                new = b + q * m.c_ns + sum(_ceil(w + k.j_ns + tau_bit_ns, k.t_ns) * k.c_ns for k in hp)
                if new == w:
                    break
                w = new
            worst = max(worst, m.j_ns + w - q * m.t_ns + m.c_ns)
        out[m.priority] = worst
    return out
