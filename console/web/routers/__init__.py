"""One APIRouter per concern: state, orders, image, link, control, ws."""
