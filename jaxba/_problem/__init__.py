"""The problem: parameter blocks, observation groups and their linearisation."""
