"""MOC2DIMES descent camera simulator: scene model + camera model + off-nominal effects."""
