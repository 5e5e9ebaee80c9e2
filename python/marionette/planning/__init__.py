"""Manipulation planning over a constraint graph (thesis 000 §2.2, §2.4, §3.2.1-3.2.3, §3.4.2).

``problem`` (models) -> ``graph_factory`` (constraint graph) -> ``planner`` (Manipulation-RRT,
shortcuts) -> ``path`` (plan file).  See README.md in this folder for the formats.
"""
