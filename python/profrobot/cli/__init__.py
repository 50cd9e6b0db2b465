"""The ``profrobot`` command line, in one package: :mod:`.main` (the parser and the torch-free
commands), :mod:`.robots` (the arguments that name a robot, poses and numbers), and the commands
that need torch, imported when they run: :mod:`.optim`, :mod:`.inverse`, :mod:`.layouts`."""
