"""Test scaffolding shared by the test packages and the benchmarks: nothing here ships in the wheel."""
