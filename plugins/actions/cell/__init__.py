"""The robot side of the cell service: the TCP gateway (:mod:`plugins.actions.cell.tcp_gateway`),
which carries the cell API's commands as ASCII lines over plain TCP for robot controllers that
cannot run zenoh (ABB RAPID, KUKA KRL, FANUC Karel, URScript), converting the vendors' pose formats
to and from the API's pose documents on the way."""
