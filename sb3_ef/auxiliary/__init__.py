"""The one interface through which an auxiliary representation loss (Ego-Foresight, SEAR, CURL) joins a host."""

from sb3_ef.auxiliary.host import AuxiliaryHostMixin
from sb3_ef.auxiliary.loss import AuxiliaryLoss, CarriesAuxiliary

__all__ = ["AuxiliaryHostMixin", "AuxiliaryLoss", "CarriesAuxiliary"]
