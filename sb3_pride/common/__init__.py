"""Building blocks shared by PEBBLE and PRIDE: buffers, reward model, queries, teachers, state entropy, the journal."""
