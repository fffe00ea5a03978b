"""Image and geometry metrics over full images and box regions (paper Sec. V)."""
