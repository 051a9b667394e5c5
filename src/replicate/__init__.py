"""buoy-swarm coverage: a reproducible replication of Kouzehgar, Meghjani & Bouffanais, *Multi-Agent
Reinforcement Learning for Dynamic Ocean Monitoring by a Swarm of Buoys* (arXiv 2012.11641)."""

__version__ = "0.1.0"
