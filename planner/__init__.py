"""Planning: grid search over the costmap, the lane graph and the lane coordinator."""
