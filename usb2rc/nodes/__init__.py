"""Node state: bindings, the neutral guard, trims, and the step that publishes the snapshot."""
