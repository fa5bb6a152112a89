"""Description: the pattern description of existing captures, inferred from their frames
(``scanqa describe``), beside decoding, which reads captures whose description is known."""
