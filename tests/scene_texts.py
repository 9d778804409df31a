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
