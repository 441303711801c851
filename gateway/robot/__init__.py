"""GR630ST robot description (Table I) and its URDF / MJCF renderings for pinocchio and MuJoCo."""
