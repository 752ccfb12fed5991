"""The layered costmap (static, obstacle, inflation layers) kept current incrementally,
and its patches."""
