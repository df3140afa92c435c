"""One APIRouter per concern: state, orders, image, images (kept pictures), link, control, ws."""
