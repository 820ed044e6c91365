"""Small hand-written worlds the flight tests share (TOML, docs/world-format.md)."""

#: A room 8 x 4 x 3 m, a pole 90 mm across just off the straight line from S (x = 1) to
#: G (x = 7), regions 0.5 m in radius.
EASY_ROOM = """
name = "easy-room"
[[plane]]
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
tag = "floor"
[[plane]]
point = [0.0, 0.0, 3.0]
normal = [0.0, 0.0, -1.0]
tag = "ceiling"
[[box]]
centre = [4.0, -0.1, 1.5]
size = [8.4, 0.2, 3.0]
tag = "wall"
[[box]]
centre = [4.0, 4.1, 1.5]
size = [8.4, 0.2, 3.0]
tag = "wall"
[[box]]
centre = [-0.1, 2.0, 1.5]
size = [0.2, 4.0, 3.0]
tag = "wall"
[[box]]
centre = [8.1, 2.0, 1.5]
size = [0.2, 4.0, 3.0]
tag = "wall"
[[cylinder]]
a = [4.0, 2.35, 0.0]
b = [4.0, 2.35, 3.0]
radius = 0.045
tag = "pole"
[[region]]
name = "S"
centre = [1.0, 2.0, 1.25]
radius = 0.5
[[region]]
name = "G"
centre = [7.0, 2.0, 1.25]
radius = 0.5
[[route]]
name = "S-G"
from = "S"
to = "G"
"""
