"""Forward dynamics of the reduced link: settings, vector field, solve, solution, table, baseline."""

from ._baseline import SeedEulerSolution as SeedEulerSolution, simulate_seed_euler as simulate_seed_euler
from ._field import FieldArgs as FieldArgs, State as State, vector_field as vector_field
from ._results import RESULTS as RESULTS
from ._settings import Settings as Settings, settings_from as settings_from
from ._solution import Solution as Solution
from ._solve import simulate as simulate, simulate_core as simulate_core
from ._table import ReducedTable as ReducedTable, build_table as build_table, build_table_core as build_table_core
