"""The one interface through which an auxiliary representation loss (Ego-Foresight, SEAR, CURL) joins a host: the
loss side (:class:`AuxiliaryLoss`) and the host side (:class:`AuxiliaryHostMixin` for every host,
:class:`AuxiliaryStepMixin` for SB3's off-policy algorithms, which train the loss as a step of its own)."""

from sb3_ef.auxiliary.host import AuxiliaryHostMixin
from sb3_ef.auxiliary.loss import AuxiliaryLoss, CarriesAuxiliary
from sb3_ef.auxiliary.step import AuxiliaryStepMixin

__all__ = ["AuxiliaryHostMixin", "AuxiliaryLoss", "AuxiliaryStepMixin", "CarriesAuxiliary"]
