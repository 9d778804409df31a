"""Assur groups and drivers: one module per kind."""

from ._base import GROUND as GROUND, AbstractGroup as AbstractGroup, Frame as Frame, Link as Link, Placement as Placement
from ._class4 import ClassIV as ClassIV
from ._drivers import Crank as Crank, Slider as Slider
from ._newton import IterativeGroup as IterativeGroup, iterative_unknowns as iterative_unknowns
from ._prp import PRP as PRP
from ._rpr import RPR as RPR
from ._rrp import PRR as PRR, RRP as RRP
from ._rrr import RRR as RRR
from ._triad import Triad as Triad

KINDS = {cls.kind: cls for cls in (Crank, Slider, RRR, RRP, PRR, RPR, PRP, Triad, ClassIV)}
