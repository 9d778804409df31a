"""Scene texts shared by several test files."""

# the slider-driven rocker of tests/joint_reference.py (slider_driven): the driver is a slider
SLIDER_DRIVEN = """
[scene]
name = "slider_driven"
gravity = [0.0, -9.81]
[ground]
O = [0.0, 0.0]
O3 = [0.0, 0.3]
[links.slider]
points = { B = [0.0, 0.0] }
com = [0.0, 0.0]
mass = 0.5
inertia = 0.0
[links.rod]
points = { B = [0.0, 0.0], C = [0.25, 0.0] }
com = [0.125, 0.0]
mass = 0.3
inertia = 0.0015625
[links.rocker]
points = { O3 = [0.0, 0.0], C = [0.2, 0.0] }
com = [0.1, 0.0]
mass = 0.4
inertia = 0.0013333333333333333
[[formation]]
group = "slider"
link = "slider"
point = "B"
guide_point = "O"
direction = [1.0, 0.0]
[[formation]]
group = "RRR"
name = "dyad"
links = ["rod", "rocker"]
joints = ["B", "O3", "C"]
mode = "left"
[state]
q0 = 0.2
"""

# a slider-driven slider-crank: the piston B, driven along the x axis through O, turns the
# crank O-A (0.1 m) through the rod A-B (0.3 m). Unlike SLIDER_DRIVEN (a rod and a rocker on
# a second ground pivot) its dyad stretches and folds on the guide: dead centres at
# q = 0.4 m (rod + crank) and 0.2 m (rod - crank)
SLIDER_DRIVEN_CRANK = """
[scene]
name = "stroke"
gravity = [0.0, -9.81]
[ground]
O = [0.0, 0.0]
[links.piston]
points = { B = [0.0, 0.0] }
mass = 0.8
inertia = 0.0
[links.crank]
points = { O = [0.0, 0.0], A = [0.1, 0.0] }
com = [0.05, 0.0]
mass = 0.5
inertia = 0.001
[links.rod]
points = { A = [0.0, 0.0], B = [0.3, 0.0] }
com = [0.15, 0.0]
mass = 1.0
inertia = 0.0075
[[formation]]
group = "slider"
link = "piston"
point = "B"
guide_point = "O"
direction = [1.0, 0.0]
[[formation]]
group = "RRR"
name = "crank_rod"
links = ["crank", "rod"]
joints = ["O", "B", "A"]
mode = "left"
"""

# the quick-return of tests/joint_reference.py (quick_return): an RPR dyad whose block slides
# on the rotating rocker (a prismatic pair with a moving guide)
QUICK_RETURN = """
[scene]
name = "quick_return_reference"
gravity = [0.0, -9.81]
[ground]
O = [0.0, 0.0]
O4 = [0.0, -0.2]
[links.crank]
points = { O = [0.0, 0.0], A = [0.1, 0.0] }
com = [0.05, 0.0]
mass = 0.3
inertia = 0.00025
[links.block]
points = { A = [0.0, 0.0] }
com = [0.0, 0.0]
mass = 0.2
inertia = 0.0001
[links.rocker]
points = { O4 = [0.0, 0.0], T = [0.5, 0.0] }
com = [0.25, 0.0]
mass = 1.0
inertia = 0.020833333333333332
[[formation]]
group = "crank"
link = "crank"
pivot = "O"
[[formation]]
group = "RPR"
name = "slot"
links = ["block", "rocker"]
joints = ["A", "O4"]
direction = [1.0, 0.0]
offset = 0.0
mode = "forward"
"""

# a motor's torque-speed line, a damper on the ram and a rotary damper at the arm's pivot,
# added to the bundled quick-return mechanism: the motor-driven shaper
SHAPER_LOADS = """
[[loads]]
type = "motor"
stall = 400.0
no_load_speed = 12.0

[[loads]]
type = "damper"
points = ["H", "S"]
coefficient = 50.0

[[loads]]
type = "rotary_damper"
joint = "O4"
coefficient = 2.0
"""

# an arm (2 kg, 0.3 m, its COM 0.15 m out) on a rough pivot O (mu 0.3, pin radius 0.04 m);
# a scene adds its [scene] header, [state] and any other loads
ROUGH_ARM = """
[ground]
O = [0.0, 0.0]
[links.arm]
points = { O = [0.0, 0.0], A = [0.3, 0.0] }
com = [0.15, 0.0]
mass = 2.0
inertia = 0.015
[[formation]]
group = "crank"
name = "arm"
link = "arm"
pivot = "O"
[[loads]]
type = "joint_friction"
joint = "O"
coefficient = 0.3
radius = 0.04
"""

# a vertical press drawn 3 deg past top dead centre, driven by its 20 kg ram: every pin
# (r = 0.02 m) and the guide rough, mu 0.2, mu_s 0.3; the toggle self-locks both ways
SELF_LOCKED_PRESS = """
[scene]
name = "self_locked_press"
gravity = [0.0, -9.81]
[sketch]
driver = "ram"
ground = ["O"]
joints = { O = [0.0, 0.0], A = [-0.005233595624294384, 0.09986295347545739], B = [0.0, 0.39981729912966085] }
[sketch.links]
crank = { joints = ["O", "A"], mass = 0.2, inertia = 0.0002 }
rod = { joints = ["A", "B"], mass = 0.5, inertia = 0.004 }
ram = { joints = ["B"], mass = 20.0, inertia = 0.0 }
[[sketch.slides]]
link = "ram"
on = "ground"
direction = [0.0, 1.0]
""" + "".join(f'[[loads]]\ntype = "joint_friction"\njoint = "{j}"\ncoefficient = 0.2\nstatic_coefficient = 0.3\n'
              f'radius = 0.02\n' for j in "OAB") + """
[[loads]]
type = "slide_friction"
pair = "ram/ground"
coefficient = 0.2
static_coefficient = 0.3
length = 0.06
"""
