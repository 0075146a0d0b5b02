"""The board at its own rate: its captures (capture), models rebuilt from them (models), their accuracy
on the emulated board (scores)."""
