"""The cage that cuts a garment into patches: the type, its checks and its file (``base``), and the automatic
cage of any garment (``auto``). The T-shirt's hand-made cage is built with the shirt
(``pbc.geometry.garment.tshirt``)."""
