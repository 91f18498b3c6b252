"""inhand-exp: hierarchical in-hand manipulation experiments (Li et al., ICRA 2020) in PyBullet."""

__version__ = "0.1.0"
