"""OATF stages per confident pole (thesis §5.3), with hysteresis; damping adaptation."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from controller.oatf import (
    OatfConfig,
    OatfFilter,
    OatfSupervisor,
    PoleOffer,
    transfer_function,
)
from protocol.messages import Interrupt, PoleParameters, decode, encode

TS = 0.005


def _sup(**cfg: object) -> OatfSupervisor:
    config = OatfConfig(sample_period_s=TS, max_stages=2, stage_hold_offers=3, **cfg)  # type: ignore[arg-type]
    return OatfSupervisor(OatfFilter([4.4], n_channels=2, config=config))


def _freqs(sup: OatfSupervisor) -> list[float]:
    return [s.frequency_hz for s in sup.oatf.stages]


def test_a_second_stage_appears_after_the_hold_and_vanishes_after_it() -> None:
    sup = _sup()
    two = [PoleOffer(frequency_hz=3.6, confidence=0.9), PoleOffer(frequency_hz=6.0, confidence=0.8)]
    for _ in range(2):
        sup.offer_poles(two, 0.9)
        assert _freqs(sup) == [3.6]
    sup.offer_poles(two, 0.9)
    assert _freqs(sup) == [3.6, 6.0]
    # the zero sits on the second mode: e^(s Ts) of its pole
    wn = 2 * np.pi * 6.0
    z = 0.09
    pole = np.exp((-z * wn + 1j * wn * np.sqrt(1 - z * z)) * TS)
    assert abs(transfer_function(pole, sup.oatf.stages)) < 1e-9
    one = [PoleOffer(frequency_hz=3.6, confidence=0.9)]
    for _ in range(2):
        sup.offer_poles(one, 0.9)
        assert len(sup.oatf.stages) == 2
    sup.offer_poles(one, 0.9)
    assert _freqs(sup) == [3.6]
    assert sup.counts.stages_created == 1 and sup.counts.stages_removed == 1


def test_a_flickering_pole_never_makes_a_stage_and_a_dip_never_removes_one() -> None:
    sup = _sup()
    two = [PoleOffer(frequency_hz=3.6, confidence=0.9), PoleOffer(frequency_hz=6.0, confidence=0.8)]
    one = two[:1]
    for k in range(20):  # present every other offer: never 3 in a row
        sup.offer_poles(two if k % 2 else one, 0.9)
        assert len(sup.oatf.stages) == 1
    for _ in range(3):
        sup.offer_poles(two, 0.9)
    assert len(sup.oatf.stages) == 2
    # confidence between the off and on levels keeps the stage; gaps shorter than the hold too
    mid = [two[0], PoleOffer(frequency_hz=6.1, confidence=0.3)]
    for k in range(20):
        sup.offer_poles(mid if k % 3 else one, 0.9)
        assert len(sup.oatf.stages) == 2
    assert sup.counts.stages_created == 1 and sup.counts.stages_removed == 0
    assert sup.oatf.stages[1].frequency_hz == pytest.approx(6.1)


def test_single_stage_default_ignores_extra_poles() -> None:
    sup = OatfSupervisor(OatfFilter([4.4], n_channels=2, config=OatfConfig(sample_period_s=TS)))
    for _ in range(10):
        sup.offer_poles([PoleOffer(frequency_hz=3.6), PoleOffer(frequency_hz=6.0)], 0.9)
    assert _freqs(sup) == [3.6]


def test_adapt_damping_follows_the_identified_damping_clipped() -> None:
    sup = _sup(adapt_damping=True, damping_limits=(0.01, 0.2))
    sup.offer_poles([PoleOffer(frequency_hz=3.6, damping_ratio=0.07, confidence=1.0)], 1.0)
    assert sup.oatf.stages[0].zeta == pytest.approx(0.07)
    sup.offer_poles([PoleOffer(frequency_hz=3.6, damping_ratio=0.5, confidence=1.0)], 1.0)
    assert sup.oatf.stages[0].zeta == pytest.approx(0.2)
    fixed = _sup()
    fixed.offer_poles([PoleOffer(frequency_hz=3.6, damping_ratio=0.07, confidence=1.0)], 1.0)
    assert fixed.oatf.stages[0].zeta == pytest.approx(0.09)


def test_interrupt_poles_carry_their_confidence_and_version() -> None:
    irq = Interrupt(
        seq=0,
        sim_time_s=1.0,
        batch_seq=0,
        poles=(
            PoleParameters(frequency_hz=3.6, damping_ratio=0.09, confidence=0.9),
            PoleParameters(frequency_hz=6.0, damping_ratio=0.05, confidence=0.1),
        ),
        confidence=0.9,
        compute_time_s=0.0,
    )
    back = decode(Interrupt, encode(irq))
    assert back == irq and back.version == 2 and back.poles[1].confidence == 0.1
    sup = _sup()
    for _ in range(5):
        sup.offer_interrupt(back)
    assert _freqs(sup) == [3.6]  # the 6 Hz pole is not confident enough for a stage
    bad = encode(irq).replace(b'"version":2', b'"version":1')
    with pytest.raises(Exception, match="version-1"):
        decode(Interrupt, bad)
    old = Interrupt(
        seq=1, sim_time_s=1.0, batch_seq=1, version=1, confidence=0.5, compute_time_s=0.0, poles=(PoleParameters(frequency_hz=3.6, damping_ratio=0.09),)
    )
    assert decode(Interrupt, encode(old)).poles[0].confidence is None
    with pytest.raises(ValidationError):
        PoleParameters(frequency_hz=3.6, damping_ratio=0.09, confidence=1.5)
