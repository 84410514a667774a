"""Plant layer: MJCF -> sampled stage (mechanics, piezo, electronics), its linearization and twin."""
